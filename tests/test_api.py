"""``streamfix.clean``: the Python API equals the command it names, checks its input, and its docs run.

* ``offline`` equals the file ``streamfix clean`` writes (a real Kinect take with a long
  gap, which the engine bridges), ``stream`` and ``live`` equal what a real
  ``streamfix serve --sync`` publishes on ``clean`` and ``live`` for the same frames;
* the module's doctests and the example in ``docs/PYTHON_API.md`` run as written.
"""
from __future__ import annotations

import doctest
import re
import subprocess
import sys

import numpy as np
import pytest

import streamfix
import streamfix.api
import streamfix.skeletons
from streamfix.cli import main
from streamfix.io import read_motion, write_motion
from streamfix.motion import Motion

from test_e2e_harness import PROJECT_ROOT, child_env, collect_until, connected_subscriber, run_replay, serve


@pytest.fixture(scope="module")
def wave(shared_data) -> Motion:
    """A real Kinect v2 take on a uniform clock (the API's frames are uniformly spaced), a 40-frame wrist gap."""
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    pos = m.positions.copy()
    pos[100:140, m.skeleton.index("WristRight")] = np.nan  # > a third of the 2 s window: bridged
    return Motion.from_positions(pos, m.skeleton, m.rate_hz, confidence=np.where(np.isfinite(pos[..., 0]), m.confidence, 0))


def test_doctests_of_the_api_and_skeleton_constructor_pass():
    for module in (streamfix.api, streamfix.skeletons):
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
        assert result.failed == 0, module.__name__
    assert doctest.testmod(streamfix.api).attempted >= 8


def test_readme_example_in_docs_runs(tmp_path):
    text = (PROJECT_ROOT / "docs" / "PYTHON_API.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, "docs/PYTHON_API.md has no python example"
    script = tmp_path / "example.py"
    script.write_text("\n".join(blocks))
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                          env=child_env(), cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert "cleaned (120, 4, 3)" in proc.stdout


def test_the_readmes_python_example_runs_as_written(tmp_path, shared_data):
    """The README's example, run from the project root as a reader would (it reads a real take
    from ../shared/data)."""
    text = (PROJECT_ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 1, "the README has one python example"
    script = tmp_path / "readme_example.py"
    script.write_text(blocks[0])
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                          env=child_env(), cwd=str(PROJECT_ROOT))
    assert proc.returncode == 0, proc.stderr
    line = proc.stdout.strip().splitlines()[-1]
    assert line.startswith("(154, 25, 3) 30 ") and line.endswith("hand samples recovered"), line


def test_offline_mode_is_what_streamfix_clean_writes(wave, tmp_path):
    src, out = tmp_path / "wave.sfrec", tmp_path / "wave.clean.sfrec"
    write_motion(wave, src)
    assert main(["clean", str(src), str(out), "--quiet"]) == 0
    given, written = read_motion(src), read_motion(out)  # .sfrec holds float32 metres
    np.testing.assert_allclose(np.diff(given.timestamps), 1.0 / wave.rate_hz, atol=1e-6)
    cleaned, recovered = streamfix.clean(given.positions, wave.rate_hz, "kinect_v2", confidence=given.confidence)
    assert cleaned.shape == wave.positions.shape and recovered.dtype == bool
    np.testing.assert_array_equal(cleaned.astype(np.float32), written.positions.astype(np.float32))
    np.testing.assert_array_equal(recovered, written.recovered)
    wrist = wave.skeleton.index("WristRight")
    assert recovered[100:140, wrist].all() and np.isfinite(cleaned).all()
    # the stream mode runs serve's schedule: the two modes really differ inside the gap
    stream, _ = streamfix.clean(wave.positions, wave.rate_hz, wave.skeleton, wave.confidence, mode="stream")
    assert np.abs(stream[100:140, wrist] - cleaned[100:140, wrist]).max() > 1e-4


def test_with_the_sensors_timestamps_a_take_with_dropped_frames_is_what_streamfix_clean_writes(shared_data, tmp_path):
    # Ges03 drops 5 frames: without its times the API saw a jump where clean fills the drop
    path = shared_data / "kinect_v2" / "Ges03_drawlines.csv"
    take = read_motion(path)
    assert (np.diff(take.timestamps) > 1.5 / take.rate_hz).any(), "the take has dropped frames"
    out = tmp_path / "draw.csv"
    assert main(["clean", str(path), str(out), "--quiet"]) == 0
    written = read_motion(out)
    cleaned, _ = streamfix.clean(take.positions, take.rate_hz, "kinect_v2", confidence=take.confidence,
                                 timestamps=take.timestamps)
    np.testing.assert_allclose(cleaned, written.positions, atol=1e-6)  # the CSV keeps 6 decimals (um)
    uniform, _ = streamfix.clean(take.positions, take.rate_hz, "kinect_v2", confidence=take.confidence)
    assert np.abs(uniform - written.positions).max() > 1e-3
    with pytest.raises(ValueError, match="increasing"):
        streamfix.clean(take.positions, take.rate_hz, "kinect_v2", timestamps=take.timestamps[::-1])
    with pytest.raises(ValueError, match=r"\(T,\)"):
        streamfix.clean(take.positions, take.rate_hz, "kinect_v2", timestamps=take.timestamps[:-1])


def test_stream_and_live_modes_equal_what_serve_publishes(wave, tmp_path):
    take = wave.slice(0, 150)
    write_motion(take, tmp_path / "take.sfrec", stream_id="take")
    got = {"live": [], "clean": []}
    with serve(tmp_path, "--sync") as sp:
        sub = connected_subscriber(sp.out, (b"sf/live/", b"sf/clean/"))
        try:
            rep = run_replay(tmp_path / "take.sfrec", sp.source, "--speed", "0")
            assert rep.returncode == 0, rep.stderr

            def collect(timeout_s=0.5) -> None:
                for r in sub.receive(timeout_s=timeout_s):
                    got[r.kind].append(r.message)

            collect_until(lambda: len(got["live"]) >= take.n_frames, collect, lambda: len(got["live"]), max_s=60)
            assert sp.terminate() == 0, sp.stderr  # flushes the frames inside the lookahead
            collect(2.0)
        finally:
            sub.close()
    for mode, topic in (("stream", "clean"), ("live", "live")):
        frames = [m for m in got[topic] if not m.filled]
        assert len(frames) == take.n_frames, topic
        served = np.stack([m.bodies[0].positions for m in frames])
        served_rec = np.stack([m.bodies[0].recovered for m in frames])
        api, api_rec = streamfix.clean(take.positions, take.rate_hz, "kinect_v2", take.confidence, mode=mode)
        # the wire carries float32 coordinates (the served engine cleans rounded input, ~0.2 um
        # at 3 m), and the cleaning's data-dependent choices (noise shares, medians) can carry
        # that rounding a little further: equal to 10 um
        np.testing.assert_allclose(api, served, rtol=0, atol=1e-5, err_msg=mode)
        np.testing.assert_array_equal(api_rec, served_rec, err_msg=mode)


def test_bad_input_raises_errors_that_say_what_is_wrong(wave):
    pos = wave.positions
    with pytest.raises(ValueError, match=r"24 joints per frame; skeleton 'kinect_v2' expects 25"):
        streamfix.clean(pos[:, :24], 30.0, "kinect_v2")
    with pytest.raises(ValueError, match=rf"\(T, J, 3\).*\({wave.n_frames}, 25\)"):
        streamfix.clean(pos[..., 0], 30.0, "kinect_v2")
    with pytest.raises(ValueError, match=r"mode must be one of 'offline', 'stream', 'live'"):
        streamfix.clean(pos, 30.0, "kinect_v2", mode="fast")
    with pytest.raises(ValueError, match="rate_hz must be a positive number"):
        streamfix.clean(pos, 0.0, "kinect_v2")
    with pytest.raises(ValueError, match=r"confidence must be \(T, J\)"):
        streamfix.clean(pos, 30.0, "kinect_v2", confidence=np.ones((wave.n_frames, 3)))
    with pytest.raises(ValueError, match="unknown skeleton 'kinect_v3'; known skeletons: .*kinect_v2"):
        streamfix.clean(pos, 30.0, "kinect_v3")
    with pytest.raises(TypeError, match="Skeleton.from_parents"):
        streamfix.clean(pos, 30.0, 25)
    with pytest.raises(ValueError, match="unknown parent 'hip'"):
        streamfix.Skeleton.from_parents("leg", ["knee", "ankle"], ["hip", "knee"])


def test_custom_skeleton_with_prior_path_cleans_and_restores_default(wave, tmp_path):
    from streamfix.prior import runtime

    card = next((PROJECT_ROOT / "streamfix" / "prior" / "models").glob("*.json"))
    before = runtime._DEFAULT_PATH
    a, _ = streamfix.clean(wave.positions, wave.rate_hz, "kinect_v2", mode="stream", prior=card)
    b, _ = streamfix.clean(wave.positions, wave.rate_hz, "kinect_v2", mode="stream")
    np.testing.assert_array_equal(a, b)  # the shipped card given by path is the default prior
    assert runtime._DEFAULT_PATH == before
    with pytest.raises((OSError, ValueError)):
        streamfix.clean(wave.positions, wave.rate_hz, "kinect_v2", prior=tmp_path / "missing.json")
    assert runtime._DEFAULT_PATH == before


def test_positions_in_millimetres_by_mistake_are_refused_but_a_far_origin_is_not(wave, tmp_path):
    # every stage is tuned in metres: 1000x too big, each sample looked like an outlier and the
    # output was metres off, silently
    for scale, unit in ((1000.0, "millimetres"), (100.0, "centimetres")):
        with pytest.raises(ValueError, match=f"metres: the median bone is .* {unit}|look like millimetres"):
            streamfix.clean(wave.positions * scale, wave.rate_hz, "kinect_v2")
    far = wave.positions[:60] + np.array([1000.0, 0.0, -1000.0])  # a world origin 1.4 km away is still metres
    cleaned, _ = streamfix.clean(far, wave.rate_hz, "kinect_v2", mode="live")
    assert np.isfinite(cleaned[np.isfinite(far).all(axis=2)]).all()
    src = tmp_path / "mm.csv"
    write_motion(Motion(wave.positions * 1000.0, wave.confidence, wave.timestamps, wave.rate_hz, wave.skeleton), src)
    assert main(["clean", str(src), str(tmp_path / "out.csv")]) == 1
    assert not (tmp_path / "out.csv").exists()
