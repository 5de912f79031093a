"""``.sfrec`` and ``streamfix record``: torn tails, corrupt records, SIGKILL mid-stream."""
from __future__ import annotations

import os
import selectors
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from test_protocol_live import MISSING_JOINT, LoopbackPublisher, expected_positions

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion, write_motion
from streamfix.io.errors import MotionFileError
from streamfix.io.recording import (
    HEADER,
    RecordingWriter,
    iter_records,
    read_recording_frames,
    scan_recording,
)
from streamfix.motion import Motion
from streamfix.skeletons import KINECT_V2, Skeleton


def _frame(seq: int) -> SkeletonFrame:
    J = KINECT_V2.n_joints
    return SkeletonFrame("s", seq, seq * 1000, "kinect_v2",
                         [BodyFrame(2, expected_positions(seq, 2, J), np.ones(J))])


def _small_recording(path: Path, n: int = 6) -> list[int]:
    """Write a skeleton message and n frames; return the byte offset after each record."""
    ends = []
    with RecordingWriter(path) as w:
        w.write_skeleton("s", KINECT_V2, 30.0)
        ends.append(path.stat().st_size)
        for seq in range(n):
            w.write_frame("raw", _frame(seq))
            ends.append(path.stat().st_size)
    return ends


def test_reader_returns_exactly_the_complete_records_at_every_cut(tmp_path):
    path = tmp_path / "a.sfrec"
    ends = _small_recording(path)
    data = path.read_bytes()
    cut_path = tmp_path / "cut.sfrec"
    for cut in range(len(HEADER), len(data) + 1, 7):
        cut_path.write_bytes(data[:cut])
        complete = sum(e <= cut for e in ends)
        frames, meta = read_recording_frames(cut_path)
        assert meta["records"] == complete
        assert [f.seq for f in frames] == list(range(max(0, complete - 1)))
        assert meta["torn_bytes"] == cut - max([len(HEADER)] + [e for e in ends if e <= cut])


def test_corrupt_record_is_skipped_and_the_rest_kept(tmp_path):
    path = tmp_path / "a.sfrec"
    ends = _small_recording(path)
    data = bytearray(path.read_bytes())
    data[ends[2] + 20] ^= 0xFF  # inside the 4th record (frame seq 2)
    path.write_bytes(bytes(data))
    frames, meta = read_recording_frames(path)
    assert [f.seq for f in frames] == [0, 1, 3, 4, 5]
    assert meta["corrupt_records"] == 1 and meta["torn_bytes"] == 0


def test_not_a_recording_and_newer_format_are_named(tmp_path):
    bad = tmp_path / "x.sfrec"
    bad.write_bytes(b"hello world")
    with pytest.raises(MotionFileError, match=r"x.sfrec: not a .sfrec recording"):
        read_recording_frames(bad)
    bad.write_bytes(b"SFREC\x00" + struct.pack("<H", 9))
    with pytest.raises(MotionFileError, match="format version 9 is newer than supported 1"):
        read_recording_frames(bad)


def test_append_cuts_a_torn_tail_and_continues(tmp_path):
    path = tmp_path / "a.sfrec"
    ends = _small_recording(path, n=4)
    with open(path, "r+b") as f:
        f.truncate(ends[-1] - 5)  # tear the last frame (seq 3)
    with pytest.raises(FileExistsError):
        RecordingWriter(path)
    with RecordingWriter(path, append=True) as w:
        w.write_frame("raw", _frame(10))
    frames, meta = read_recording_frames(path)
    assert [f.seq for f in frames] == [0, 1, 2, 10]
    assert meta["torn_bytes"] == 0 and scan_recording(path).complete


def test_motion_round_trip_real_kinect_recording(tmp_path, shared_data):
    m = read_motion(shared_data / "kinect_v2" / "seated_joints.csv")
    path = tmp_path / "seated.sfrec"
    write_motion(m, path)
    back = read_motion(path)
    assert back.n_frames == m.n_frames and back.skeleton == m.skeleton
    assert back.rate_hz == pytest.approx(m.rate_hz)
    np.testing.assert_array_equal(np.isnan(back.positions), np.isnan(m.positions))
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6, equal_nan=True)  # float32 on the wire
    np.testing.assert_array_equal(back.confidence, m.confidence)  # 0, 0.5, 1 are exact in float32
    np.testing.assert_allclose(back.timestamps, m.timestamps, atol=1e-9)


def test_custom_skeleton_and_recovered_mask_survive_without_the_registry(tmp_path):
    sk = Skeleton("only_in_this_file", ("root", "mid", "tip"), ((0, 1), (1, 2)))
    rng = np.random.default_rng(1)
    pos = rng.normal(size=(20, 3, 3))
    conf = np.ones((20, 3))
    conf[5, 1] = 0
    rec = rng.random((20, 3)) < 0.3
    m = Motion(pos, conf, np.arange(20) / 50.0, 50.0, sk, recovered=rec)
    path = tmp_path / "custom.sfrec"
    write_motion(m, path)
    back = read_motion(path)
    assert back.skeleton == sk and back.rate_hz == 50.0 and back.meta["kind"] == "clean"
    np.testing.assert_array_equal(back.recovered, rec)
    assert np.isnan(back.positions[5, 1]).all()


def _read_acks(proc: subprocess.Popen, n: int, timeout_s: float) -> list[tuple[str, int]]:
    """Read ``ack TOPIC SEQ`` lines from the recorder until n arrived (or fail)."""
    acks: list[tuple[str, int]] = []
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    buf = b""
    while len(acks) < n:
        remaining = deadline - time.monotonic()
        if remaining <= 0 or proc.poll() is not None:
            break
        if not sel.select(min(remaining, 0.5)):
            continue
        chunk = os.read(proc.stdout.fileno(), 65536)
        if not chunk:
            break
        buf += chunk
        *lines, buf = buf.split(b"\n")
        for line in lines:
            word, topic, seq = line.decode().split()
            assert word == "ack"
            acks.append((topic, int(seq)))
    sel.close()
    return acks


def _start_recorder(endpoint: str, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "streamfix", "record", endpoint, str(out), "--ack", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )


def test_sigkilled_recorder_leaves_every_acknowledged_frame(tmp_path):
    out = tmp_path / "killed.sfrec"
    with LoopbackPublisher(kind="raw", rate_hz=300, garbage_every=7) as lp:
        # --fsync 3600: no fsync while running, so only the write-per-record design protects the data
        proc = _start_recorder(lp.endpoint, out, "--topic", "raw", "--fsync", "3600")
        try:
            acks = _read_acks(proc, 60, timeout_s=30)
            assert len(acks) >= 60, proc.stderr.read().decode() if proc.poll() is not None else "no acks"
            proc.send_signal(signal.SIGKILL)  # mid-stream: the publisher is still sending
            proc.wait(10)
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.stdout.close()
            proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    frames, meta = read_recording_frames(out)
    got = [f.seq for f in frames]
    acked = [seq for _, seq in acks]
    assert set(acked) <= set(got), "an acknowledged frame is missing"
    assert got == list(range(got[0], got[0] + len(got))), "in order, nothing lost on loopback"
    assert "kinect0" in meta["skeletons"], "the skeleton message is in the file"
    assert meta["corrupt_records"] == 0 and meta["stopped"] is None
    J = KINECT_V2.n_joints
    ok = np.arange(J) != MISSING_JOINT
    for f in frames:
        assert [b.body_id for b in f.bodies] == [1, 4]
        np.testing.assert_array_equal(f.bodies[0].positions[ok], expected_positions(f.seq, 1, J)[ok])
        assert np.isnan(f.bodies[0].positions[MISSING_JOINT]).all()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_closes_the_recording_cleanly(tmp_path, signum):
    out = tmp_path / "term.sfrec"
    with LoopbackPublisher(kind="clean", rate_hz=300) as lp:
        proc = _start_recorder(lp.endpoint, out, "--topic", "clean")
        try:
            acks = _read_acks(proc, 10, timeout_s=30)
            assert len(acks) >= 10
            proc.send_signal(signum)
            _, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 0, err
    assert f"signal {signum.name}".encode() in err
    scan = scan_recording(out)
    assert scan.complete and scan.corrupt == 0
    frames, _ = read_recording_frames(out)
    assert {seq for _, seq in acks} <= {f.seq for f in frames}


def test_record_count_stops_and_reads_back_as_motion(tmp_path):
    with LoopbackPublisher(kind="clean", rate_hz=300) as lp:
        counted = tmp_path / "count.sfrec"
        proc = subprocess.run(
            [sys.executable, "-m", "streamfix", "record", lp.endpoint, str(counted), "--topic", "clean",
             "--count", "120", "--duration", "30"],
            capture_output=True, text=True, timeout=60,
        )
    assert proc.returncode == 0, proc.stderr
    assert "count reached: 120 frames" in proc.stderr
    motion = read_motion(counted)
    assert motion.n_frames == 120 and motion.meta["kind"] == "clean" and motion.meta["body_id"] == 1
    seq = motion.meta["seq"]
    J = KINECT_V2.n_joints
    want = np.stack([expected_positions(int(s), 1, J) for s in seq])
    want[:, MISSING_JOINT] = np.nan
    np.testing.assert_array_equal(motion.positions, want)
    # 120 frames at <= 300 Hz span >= 0.4 s: two or more repeats of the skeleton message
    # (every 0.2 s) arrived, and it is stored once (when first seen), not at every repeat
    assert [r.topic for r in iter_records(counted)].count(b"sf/meta/kinect0") == 1
