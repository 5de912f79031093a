"""Kinect v2 CSV reader/writer against the real LabanotationSuite recordings."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.io.errors import MotionFileError
from streamfix.io.kinect_csv import parse_kinect_csv_line, read_kinect_csv, write_kinect_csv
from streamfix.motion import CONFIDENCE_INFERRED, Motion
from streamfix.skeletons import KINECT_V2

# frame counts from ../shared/data/README.md
FRAMES = {
    "Ges01_wavehand.csv": 154,
    "Ges02_balancinghands.csv": 161,
    "Ges03_drawlines.csv": 213,
    "Ges04_comehere.csv": 172,
    "seated_joints.csv": 371,
}


@pytest.mark.parametrize("name", sorted(FRAMES))
def test_reads_every_recording(shared_data, name):
    m = read_kinect_csv(shared_data / "kinect_v2" / name)
    assert m.n_frames == FRAMES[name]
    assert m.skeleton is KINECT_V2 and m.n_joints == 25
    assert 29.0 < m.rate_hz < 31.0  # estimated from the timestamps, Kinect v2 is ~30 Hz
    assert np.all(np.diff(m.timestamps) > 0)
    # camera space metres: a person 0.5..5 m in front of the sensor
    z = m.positions[..., 2][m.observed]
    assert 0.5 < np.median(z) < 5.0
    # head above spine base in camera y (y up)
    head, base = KINECT_V2.index("Head"), KINECT_V2.index("SpineBase")
    assert np.nanmedian(m.positions[:, head, 1] - m.positions[:, base, 1]) > 0.3
    assert set(np.unique(m.confidence)) <= {0.0, 0.5, 1.0}


def test_seated_has_inferred_legs(shared_data):
    m = read_kinect_csv(shared_data / "kinect_v2" / "seated_joints.csv")
    inferred = m.confidence == CONFIDENCE_INFERRED
    assert inferred.mean() > 0.2  # the README: legs are often inferred
    legs = [KINECT_V2.index(n) for n in ("AnkleLeft", "FootLeft", "AnkleRight", "FootRight")]
    arms = [KINECT_V2.index(n) for n in ("ShoulderLeft", "ShoulderRight", "Head")]
    assert inferred[:, legs].mean() > 5 * inferred[:, arms].mean()
    # inferred samples are still observed (low confidence), not NaN
    assert np.isfinite(m.positions[inferred]).all()


def test_round_trip(shared_data, tmp_path):
    m = read_kinect_csv(shared_data / "kinect_v2" / "seated_joints.csv")
    # punch some missing samples in, they must come back missing
    m.positions[10:20, 3] = np.nan
    m.confidence[10:20, 3] = 0.0
    out = tmp_path / "rt.csv"
    write_kinect_csv(m, out)
    r = read_kinect_csv(out)
    assert r.n_frames == m.n_frames
    np.testing.assert_array_equal(r.observed, m.observed)
    np.testing.assert_array_equal(r.confidence, m.confidence)
    np.testing.assert_allclose(r.positions, m.positions, atol=1e-8, equal_nan=True)
    np.testing.assert_allclose(r.timestamps, m.timestamps, atol=1e-7)
    assert r.rate_hz == pytest.approx(m.rate_hz)


def test_rate_is_estimated_not_assumed(tmp_path):
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(40, 25, 3))
    m = Motion.from_positions(pos, KINECT_V2, rate_hz=15.0, t0=3.0)
    write_kinect_csv(m, tmp_path / "m.csv")
    r = read_kinect_csv(tmp_path / "m.csv")
    assert r.rate_hz == pytest.approx(15.0, rel=1e-6)


def _good_line(shared_data, k=0):
    return (shared_data / "kinect_v2" / "Ges01_wavehand.csv").read_text().splitlines()[k]


def _write(tmp_path, lines, name="Ges01.csv"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_wrong_field_count_names_file_line_and_counts(shared_data, tmp_path):
    lines = [_good_line(shared_data, k) for k in range(20)]
    lines[16] = ",".join(lines[16].split(",")[:-5]) + ","  # drop a joint's 4 fields
    p = _write(tmp_path, lines)
    with pytest.raises(MotionFileError) as e:
        read_kinect_csv(p)
    msg = str(e.value)
    assert "Ges01.csv line 17" in msg and "expected 101 fields" in msg and "got 97" in msg
    assert e.value.line == 17


def test_non_numeric_value(shared_data, tmp_path):
    lines = [_good_line(shared_data, k) for k in range(5)]
    parts = lines[3].split(",")
    parts[1 + 4 * 3 + 1] = "abc"  # Head y
    lines[3] = ",".join(parts)
    with pytest.raises(MotionFileError, match=r"line 4: joint 3 \(Head\) y is not a number: 'abc'"):
        read_kinect_csv(_write(tmp_path, lines))


def test_bad_tracking_state(shared_data, tmp_path):
    lines = [_good_line(shared_data, k) for k in range(5)]
    parts = lines[1].split(",")
    parts[1 + 4 * 7 + 3] = "3"
    lines[1] = ",".join(parts)
    with pytest.raises(MotionFileError, match=r"line 2: joint 7 \(HandLeft\) trackingState must be 0, 1 or 2, got 3"):
        read_kinect_csv(_write(tmp_path, lines))


def test_timestamps_must_increase(shared_data, tmp_path):
    lines = [_good_line(shared_data, k) for k in range(5)]
    lines[3] = lines[1]
    with pytest.raises(MotionFileError, match=r"line 4: timestamp .* is not after"):
        read_kinect_csv(_write(tmp_path, lines))


def test_empty_file(tmp_path):
    with pytest.raises(MotionFileError, match="empty.csv: no frames"):
        read_kinect_csv(_write(tmp_path, [""], "empty.csv"))


def test_text_without_frame_lines_says_so(tmp_path):
    with pytest.raises(MotionFileError, match=r"words.csv: no frames: 1 line\(s\) of text but no frame line"):
        read_kinect_csv(_write(tmp_path, ["hello world"], "words.csv"))


def test_nan_coordinate_of_a_tracked_joint_is_missing_not_a_bad_file(shared_data, tmp_path):
    """A NaN/inf coordinate makes that joint missing whatever its trackingState says; the
    frame's other joints and the other frames are read as they are, and the count is kept."""
    lines = [_good_line(shared_data, k) for k in range(6)]
    parts = lines[2].split(",")
    assert parts[1 + 4 * 9 + 3] == "2"  # WristRight tracked
    parts[1 + 4 * 9 + 1] = "nan"
    parts[1 + 4 * 9 + 2] = "inf"
    lines[2] = ",".join(parts)
    m = read_kinect_csv(_write(tmp_path, lines))
    good = read_kinect_csv(_write(tmp_path, [_good_line(shared_data, k) for k in range(6)], "good.csv"))
    assert m.n_frames == 6 and m.meta["nonfinite_joints"] == 1
    assert m.confidence[2, 9] == 0 and np.isnan(m.positions[2, 9]).all()
    keep = np.ones(m.positions.shape[:2], dtype=bool)
    keep[2, 9] = False
    np.testing.assert_array_equal(m.positions[keep], good.positions[keep])
    assert "nonfinite_joints" not in good.meta


def test_state_zero_is_missing_whatever_the_coordinates(shared_data):
    line = _good_line(shared_data)
    parts = line.split(",")
    parts[1 + 4 * 5 + 3] = "0"
    ticks, pos, conf = parse_kinect_csv_line(",".join(parts))
    assert ticks == int(parts[0])
    assert conf[5] == 0 and np.isnan(pos[5]).all()
    assert np.isfinite(np.delete(pos, 5, axis=0)).all()


def test_writer_rejects_other_skeletons(tmp_path):
    from streamfix.skeletons import AZURE_KINECT

    m = Motion.from_positions(np.zeros((3, 32, 3)), AZURE_KINECT, 30.0)
    with pytest.raises(ValueError, match="25-joint kinect_v2"):
        write_kinect_csv(m, tmp_path / "x.csv")


def test_fixed_decimals(shared_data, tmp_path):
    m = read_kinect_csv(shared_data / "kinect_v2" / "Ges02_balancinghands.csv")
    write_kinect_csv(m, tmp_path / "d.csv", decimals=4)
    r = read_kinect_csv(tmp_path / "d.csv")
    np.testing.assert_allclose(r.positions, m.positions, atol=0.5e-4 + 1e-12, equal_nan=True)
    np.testing.assert_array_equal(r.confidence, m.confidence)
    assert (tmp_path / "d.csv").stat().st_size < (shared_data / "kinect_v2" / "Ges02_balancinghands.csv").stat().st_size


def test_header_line_is_skipped_but_later_text_is_an_error(shared_data, tmp_path):
    lines = [_good_line(shared_data, k) for k in range(4)]
    header = "Timestamp," + ",".join(f"{n}_{c}" for n in KINECT_V2.joint_names for c in ("X", "Y", "Z", "State"))
    m = read_kinect_csv(_write(tmp_path, [header] + lines, "h.csv"))
    assert m.n_frames == 4
    with pytest.raises(MotionFileError, match=r"h2\.csv line 3: timestamp is not a number: 'Timestamp'"):
        read_kinect_csv(_write(tmp_path, lines[:2] + [header] + lines[2:], "h2.csv"))
