"""Readers' errors say what is wrong in a line a person can read: real files written here."""
from __future__ import annotations

import pytest

from streamfix.io import MotionFileError, read_motion
from streamfix.io.recording import RecordingWriter


def test_a_bvh_that_is_not_one_shows_the_start_of_its_first_token_not_all_of_it(shared_data, tmp_path):
    fake = tmp_path / "take.bvh"  # a Kinect CSV saved with the wrong extension: one 2 KB first line
    fake.write_text((shared_data / "kinect_v2" / "Ges01_wavehand.csv").read_text())
    with pytest.raises(MotionFileError) as exc:
        read_motion(fake)
    text = str(exc.value)
    assert "line 1" in text and "expected 'HIERARCHY'" in text and "characters)" in text
    assert len(text) < 300


def test_a_recording_without_frames_says_what_it_held(tmp_path):
    empty = tmp_path / "empty.sfrec"
    RecordingWriter(empty).close()  # a recorder that stopped before any frame came
    with pytest.raises(MotionFileError) as exc:
        read_motion(empty)
    assert "no frames in the recording (0 records; skipped: none)" in str(exc.value)
