"""``streamfix clean`` fills the real gaps of a C3D marker take (issue 5 item 3)."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.cli import main
from streamfix.io import read_motion, write_motion


@pytest.fixture(scope="module")
def rolling_slice(shared_data, tmp_path_factory):
    """Frames 900-1250 (2 s at 175 Hz) of 03_rolling.c3d, real gaps included."""
    m = read_motion(shared_data / "c3d" / "03_rolling.c3d").slice(900, 1250)
    path = tmp_path_factory.mktemp("rolling") / "rolling350.c3d"
    write_motion(m, path)
    return path, read_motion(path)


@pytest.mark.parametrize("ext", [".c3d", ".sfrec"])
def test_clean_fills_real_marker_gaps_and_flags_them(rolling_slice, tmp_path, capsys, ext):
    src, m = rolling_slice
    seen = m.observed.any(axis=0)  # markers observed at least somewhere
    gaps = ~m.observed & seen[None, :]
    assert gaps.sum() > 3000  # real gaps, not a toy
    out = tmp_path / f"clean{ext}"
    assert main(["clean", str(src), str(out)]) == 0
    line = capsys.readouterr().out.strip().splitlines()
    assert len(line) == 1
    filled_reported = int(line[0].split(" gap samples filled")[0].rsplit(" ", 1)[-1])
    c = read_motion(out)
    assert c.n_frames == m.n_frames and c.n_joints == m.n_joints
    fin = np.isfinite(c.positions).all(axis=2)
    assert fin[:, seen].all()  # no missing sample left where the marker exists
    assert filled_reported == int(gaps.sum())
    # observed samples are cleaned, not replaced
    d = np.linalg.norm(c.positions - m.positions, axis=2)[m.observed]
    assert np.median(d) < 0.01
    if ext == ".sfrec":  # the format that keeps the flag
        assert c.recovered is not None and c.recovered[gaps].all()
        assert (c.confidence[gaps] <= 0.5).all()
    print(f"03_rolling[900:1250]: {int(gaps.sum())} gap samples filled; median change of observed {np.median(d) * 1000:.1f} mm")


def test_clean_training_option_accepts_a_reference_take(rolling_slice, shared_data, tmp_path, capsys):
    src, m = rolling_slice
    ref = read_motion(shared_data / "c3d" / "03_rolling.c3d").slice(1800, 2150)
    ref_path = tmp_path / "ref.c3d"
    write_motion(ref, ref_path)
    out = tmp_path / "clean.sfrec"
    assert main(["clean", str(src), str(out), "--training", str(ref_path)]) == 0
    line = capsys.readouterr().out
    assert "2 training takes" in line
    c = read_motion(out)
    assert np.isfinite(c.positions).all(axis=2)[:, m.observed.any(axis=0)].all()


def test_a_joint_file_with_long_gaps_goes_to_the_engine_as_it_is(shared_data):
    """A skeleton's long gaps are the engine's to bridge (history, prior, time), not the PCA gap
    filler's: the filler left 2.6x the engine's error on the sensor protocol's lost limbs
    (streamfix/cleaning.py). Reference takes given for it are said to go unused."""
    from streamfix.cleaning import clean_recording
    from streamfix.streaming.config import EngineConfig
    from streamfix.streaming.offline import clean_motion

    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    pos = m.positions.copy()
    pos[100:160, m.skeleton.index("WristRight")] = np.nan  # 2 s: a long gap on either schedule
    m = type(m)(pos, np.where(np.isfinite(pos[..., 0]), m.confidence, 0.0), m.timestamps, m.rate_hz, m.skeleton)
    result = clean_recording(m, training=[str(shared_data / "kinect_v2" / "Ges02_balancinghands.csv")])
    assert result.gapfilled is None and any("reference takes unused" in n for n in result.notes)
    engine, _ = clean_motion(m, EngineConfig.for_files(m.rate_hz))
    np.testing.assert_array_equal(result.motion.positions, engine.positions)
    assert result.motion.recovered[100:160, m.skeleton.index("WristRight")].all()
