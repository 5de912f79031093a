"""A truncated TRC file is refused, naming the file and the line, as the other readers refuse one.

The TRC is written from a real Kinect v2 take (../shared/data) and then cut the way a
copy or a write stopped mid-way cuts it: inside a row, inside the last number, or at a
row's end before NumFrames rows. Read on, a torn row became a frame with joints missing
and a half-written number a wrong coordinate (z = 0.025 m instead of 2.59 m).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from streamfix.cli import main
from streamfix.io import MotionFileError, read_motion
from streamfix.io.trc import read_trc, write_trc

TAKE = "kinect_v2/Ges01_wavehand.csv"  # 154 frames, 25 joints: 77 fields a row
LAST = 160  # the last frame's line: 6 header lines (the 6th blank), then frame k on line 6 + k


@pytest.fixture(scope="module")
def full_trc(shared_data, tmp_path_factory) -> Path:
    """The real take written as TRC (mm, 6 decimals), every row ending in a newline."""
    path = tmp_path_factory.mktemp("trc") / "take.trc"
    write_trc(read_motion(shared_data / TAKE), path)
    return path


def _row_span(text: str, line: int) -> tuple[int, int]:
    """Start and end (before its newline) of 1-based ``line`` in ``text``."""
    start = 0
    for _ in range(line - 1):
        start = text.index("\n", start) + 1
    return start, text.index("\n", start)


def _cut(tmp_path: Path, text: str, at: int, name: str = "torn.trc") -> Path:
    path = tmp_path / name
    path.write_text(text[:at])
    return path


def test_cut_inside_a_row_names_the_line_and_the_field_count(full_trc, tmp_path):
    text = full_trc.read_text()
    start, end = _row_span(text, 106)  # frame 100
    row = text[start:end]
    at = start + len("\t".join(row.split("\t")[:40])) + 3  # three characters into field 41
    with pytest.raises(MotionFileError, match=r"torn\.trc line 106: truncated: .*expected 77 fields .*got 41"):
        read_trc(_cut(tmp_path, text, at))


def test_cut_inside_the_last_number_is_not_read_as_a_value(full_trc, tmp_path):
    """All 77 fields are there, but the last Z is half-written ('2607.1' of '2607.157...')."""
    text = full_trc.read_text()
    _, end = _row_span(text, LAST)
    with pytest.raises(MotionFileError, match=r"torn\.trc line 160: truncated: .*no newline.*decimal"):
        read_trc(_cut(tmp_path, text, end - 5))


def test_fewer_rows_than_numframes(full_trc, tmp_path):
    text = full_trc.read_text()
    _, end = _row_span(text, 105)  # 99 whole frames, each line ending in a newline
    with pytest.raises(MotionFileError, match=r"torn\.trc line \d+: truncated: .*NumFrames 154, 99 frame rows"):
        read_trc(_cut(tmp_path, text, end + 1))


def test_a_short_row_inside_the_file_is_an_error(full_trc, tmp_path):
    lines = full_trc.read_text().split("\n")
    lines[50] = "\t".join(lines[50].split("\t")[:30])  # frame 45 lost its last 47 fields
    path = tmp_path / "short_row.trc"
    path.write_text("\n".join(lines))
    with pytest.raises(MotionFileError, match=r"short_row\.trc line 51: expected 77 fields .*got 30"):
        read_trc(path)


@pytest.mark.parametrize("row", [60, LAST])  # a frame in the middle (the rest cut off), the last frame
def test_every_cut_inside_a_row_is_refused(full_trc, tmp_path, row):
    """Byte by byte through the row: each cut is an error, never a silently shorter motion.
    Only the cut after the last frame's last digit leaves the whole data (the newline lost).
    (The cut file is the same 154-frame take; every cut is read, about 1000 per row.)"""
    text = full_trc.read_text()
    start, end = _row_span(text, row)
    whole = read_trc(full_trc)
    for at in range(start, end + 1):
        path = _cut(tmp_path, text, at)
        if row == LAST and at == end:
            np.testing.assert_array_equal(read_trc(path).positions, whole.positions)
            continue
        with pytest.raises(MotionFileError, match=r"torn\.trc line \d+: truncated"):
            read_trc(path)


def test_a_writer_s_trailing_tab_shows_a_cut_in_the_last_number(full_trc, tmp_path):
    """OpenSim ends every value with a tab: a last row without it was cut, even when its
    last value looks whole (here only the tab is gone, so the decimals do not show it)."""
    lines = full_trc.read_text().split("\n")
    lines = lines[:6] + [ln + "\t" for ln in lines[6:] if ln]
    text = "\n".join(lines) + "\n"
    _, end = _row_span(text, LAST)
    (tmp_path / "whole.trc").write_text(text)
    assert read_trc(tmp_path / "whole.trc").n_frames == 154
    with pytest.raises(MotionFileError, match=r"line 160: truncated: .*77 fields, the row before it 78"):
        read_trc(_cut(tmp_path, text, end - 1))


def test_a_whole_file_without_a_final_newline_still_reads(full_trc, tmp_path):
    path = tmp_path / "no_newline.trc"
    path.write_text(full_trc.read_text().rstrip("\n"))
    np.testing.assert_array_equal(read_trc(path).positions, read_trc(full_trc).positions)


def test_clean_refuses_a_torn_trc_and_writes_nothing(full_trc, tmp_path, capsys):
    text = full_trc.read_text()
    start, end = _row_span(text, 106)
    torn = _cut(tmp_path, text, (start + end) // 2)
    out = tmp_path / "out.csv"
    assert main(["clean", str(torn), str(out), "--quiet"]) != 0
    assert "torn.trc line 106: truncated" in capsys.readouterr().err
    assert not out.exists()
