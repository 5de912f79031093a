"""Every real Kinect v2 recording through real ``streamfix replay`` -> ``streamfix serve`` processes.

Each recording is replayed (as fast as the service takes it) into one ``streamfix serve``
(each file is its own stream); a subscriber collects ``live`` and ``clean``. Then:

* every input frame appears exactly once on ``live`` and once on ``clean``, in input
  order: the real (non-filled) output frames carry exactly the input sensor times, in
  order, and the output sequence numbers run consecutively without duplicates (filled
  frames for sensor drops take their own numbers, as ``protocol/SPEC.md`` says);
* the ``clean`` stream matches ``streamfix clean`` on the same file within 5 mm AJE,
  except within one window of either end.

The service runs with ``--sync`` (windows solved on the input thread) so that its output
does not depend on how loaded the test machine is: in threaded mode a busy machine
makes the engine degrade (fewer iterations), which is the point of threaded mode but
would make the comparison depend on load. Threaded mode is exercised by the bad-input
and shutdown tests.
"""
from __future__ import annotations

import numpy as np

from streamfix.cli import main as cli_main
from streamfix.core.metrics import aje
from streamfix.io import read_motion
from streamfix.service.playback import motion_frames
from streamfix.streaming.engine import EngineConfig

from test_e2e_harness import collect_until, connected_subscriber, run_replay, serve

AJE_TOLERANCE_M = 0.005


def _clean_reference(path, tmp_path) -> np.ndarray:
    """``streamfix clean IN OUT --schedule serve`` (the command, run in this process): cleaned
    real frames (T, J, 3) on serve's schedule."""
    out = tmp_path / f"{path.stem}.clean.sfrec"
    assert cli_main(["clean", str(path), str(out), "--schedule", "serve", "--quiet"]) == 0
    return read_motion(out).positions


def test_every_kinect_recording_comes_out_once_in_order_and_matches_offline_clean(tmp_path, shared_data):
    files = sorted((shared_data / "kinect_v2").glob("*.csv"))
    assert len(files) == 5
    motions = {f.stem: read_motion(f) for f in files}
    expected_times = {
        stem: [fr.sensor_time_ns for _, fr in motion_frames(m, stem)] for stem, m in motions.items()
    }
    got = {stem: {"live": [], "clean": []} for stem in motions}

    def collect(sub, timeout_s):
        for r in sub.receive(timeout_s=timeout_s):
            got[r.stream][r.kind].append(r.message)

    with serve(tmp_path, "--sync") as sp:
        sub = connected_subscriber(sp.out, (b"sf/live/", b"sf/clean/"))
        try:
            for f in files:
                rep = run_replay(f, sp.source, "--speed", "0")
                assert rep.returncode == 0, rep.stderr
                collect(sub, 0.05)
            # while the service works through them, run `streamfix clean` on the same files
            references = {f.stem: _clean_reference(f, tmp_path) for f in files}
            collect_until(
                lambda: all(sum(not m.filled for m in got[s]["live"]) >= motions[s].n_frames for s in motions),
                lambda: collect(sub, 0.5),
                lambda: sum(len(v["live"]) for v in got.values()),
            )
            assert sp.terminate() == 0, sp.stderr  # flushes the frames still inside their lookahead
            collect(sub, 3.0)
        finally:
            sub.close()

    for stem, motion in motions.items():
        for kind in ("live", "clean"):
            msgs = got[stem][kind]
            seqs = [m.seq for m in msgs]
            assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), f"{stem} {kind}: seq not consecutive"
            real = [m for m in msgs if not m.filled]
            assert [m.sensor_time_ns for m in real] == expected_times[stem], (
                f"{stem} {kind}: {len(real)} real frames out for {motion.n_frames} in, or not in order"
            )
        clean = np.stack([m.bodies[0].positions for m in got[stem]["clean"] if not m.filled])
        reference = references[stem]
        assert reference.shape == clean.shape
        window = EngineConfig(rate_hz=motion.rate_hz).window
        inner = slice(window, motion.n_frames - window)
        err = aje(clean[inner], reference[inner])
        print(f"{stem}: {err * 1e3:.4f} mm AJE vs offline")
        assert err < AJE_TOLERANCE_M, f"{stem}: clean differs from streamfix clean by {err * 1e3:.2f} mm AJE"
