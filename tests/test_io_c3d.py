"""C3D reader/writer (ezc3d) against the real marker files."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.io.c3d import read_c3d, write_c3d
from streamfix.io.errors import MotionFileError
from streamfix.motion import Motion
from streamfix.skeletons import get_skeleton

# from ../shared/data/README.md
FILES = {"85_02.c3d": (41, 810, 120.0), "135_02.c3d": (41, 5202, 120.0), "03_rolling.c3d": (68, 2305, 175.0)}


@pytest.mark.parametrize("name", sorted(FILES))
def test_reads_real_files(shared_data, name):
    markers, frames, rate = FILES[name]
    m = read_c3d(shared_data / "c3d" / name)
    assert (m.n_joints, m.n_frames, m.rate_hz) == (markers, frames, rate)
    assert m.skeleton.n_bones == 0  # markers are not joints
    assert get_skeleton(m.skeleton.name) == m.skeleton and m.skeleton.name.startswith("c3d:")
    assert np.allclose(np.diff(m.timestamps), 1.0 / rate)
    # millimetres -> metres: a human-size marker cloud (extent 0.3..3 m in each frame)
    extent = np.nanmax(m.positions, axis=1) - np.nanmin(m.positions, axis=1)
    assert 0.3 < np.nanmedian(extent.max(axis=1)) < 3.0
    # missing is NaN with confidence 0, never (0,0,0)
    assert not (m.positions == 0).all(axis=2).any()
    assert np.array_equal(np.isnan(m.positions).any(axis=2), ~m.observed)


def test_gap_fractions_match_the_readme(shared_data):
    rolling = read_c3d(shared_data / "c3d" / "03_rolling.c3d")
    assert 1 - rolling.observed.mean() == pytest.approx(0.23, abs=0.01)
    assert read_c3d(shared_data / "c3d" / "85_02.c3d").observed.all()


def test_round_trip(shared_data, tmp_path):
    m = read_c3d(shared_data / "c3d" / "03_rolling.c3d").slice(0, 400)
    out = tmp_path / "rt.c3d"
    write_c3d(m, out)
    r = read_c3d(out)
    assert r.skeleton == m.skeleton and r.rate_hz == m.rate_hz
    np.testing.assert_array_equal(r.observed, m.observed)
    assert (~m.observed).any()  # the slice does carry gaps
    np.testing.assert_allclose(r.positions, m.positions, atol=1e-6, equal_nan=True)  # float32 mm
    np.testing.assert_allclose(r.timestamps, m.timestamps, atol=1e-9)


def test_missing_written_by_c3d_convention(tmp_path):
    import ezc3d

    from streamfix.io.c3d import marker_skeleton

    pos = np.random.default_rng(0).normal(size=(6, 3, 3))
    pos[2, 1] = np.nan
    m = Motion.from_positions(pos, marker_skeleton(["A", "B", "B"]), 100.0)
    assert m.skeleton.joint_names == ("A", "B", "B#2")
    write_c3d(m, tmp_path / "m.c3d")
    c = ezc3d.c3d(str(tmp_path / "m.c3d"))
    assert c["data"]["meta_points"]["residuals"][0, 1, 2] < 0  # residual -1 = invalid point
    r = read_c3d(tmp_path / "m.c3d")
    assert not r.observed[2, 1] and r.observed.sum() == m.observed.sum()


def test_truncated_file_names_the_frame(shared_data, tmp_path):
    data = (shared_data / "c3d" / "85_02.c3d").read_bytes()
    p = tmp_path / "cut.c3d"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(MotionFileError, match=r"cut\.c3d frame \d+: truncated: the header declares 810 frames"):
        read_c3d(p)


def test_garbage_file(tmp_path):
    p = tmp_path / "junk.c3d"
    p.write_bytes(b"not a c3d file at all" * 20)
    with pytest.raises(MotionFileError, match=r"junk\.c3d: not a readable C3D file"):
        read_c3d(p)
