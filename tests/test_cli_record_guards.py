"""``streamfix record`` never destroys a recording when it fails, and refuses numbers that stop it at once.

Real files (an existing recording made from a real Kinect v2 take), real ZeroMQ sockets
on 127.0.0.1. The endpoint is connected or bound before OUT is opened, so a start that
fails (a bad endpoint, a busy port) leaves an existing recording byte for byte as it was
and creates no file; ``--overwrite`` writes beside OUT and takes OUT's name at the first
record, so a kill after an acknowledged frame still leaves it in OUT, and a write that
fails before any record keeps the old recording. ``--count 0``, ``--duration -1`` and
their like exit 2 naming the option (``record`` once stopped at once with exit 0).
"""
from __future__ import annotations

import resource
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from streamfix.cli import main
from streamfix.io import read_motion, write_motion
from streamfix.io.recording import read_recording_frames, scan_recording

from test_e2e_harness import PROJECT_ROOT, child_env
from test_protocol_live import LoopbackPublisher
from test_record_sfrec import _read_acks


@pytest.fixture
def old_recording(shared_data, tmp_path) -> tuple[Path, bytes]:
    """A real recording (Ges01_wavehand as .sfrec) that a failed run must not touch."""
    path = tmp_path / "take.sfrec"
    write_motion(read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), path)
    return path, path.read_bytes()


def _record(*args: str, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamfix", "record", *args], capture_output=True, text=True,
                          timeout=timeout, env=child_env(), cwd=str(PROJECT_ROOT), **kw)


def _start(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "streamfix", "record", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=child_env(), cwd=str(PROJECT_ROOT), **kw)


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_bad_endpoint_with_overwrite_leaves_the_recording_untouched(old_recording, tmp_path):
    path, before = old_recording
    r = _record("bogus", str(path), "--overwrite", "--duration", "5")
    assert r.returncode == 2 and "cannot connect to 'bogus'" in r.stderr, r.stderr
    assert path.read_bytes() == before, "a failed start destroyed the recording"
    assert _names(tmp_path) == ["take.sfrec"]  # no temporary file left either


def test_a_busy_port_creates_no_file_and_a_rerun_is_not_refused(tmp_path):
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    out = tmp_path / "new.sfrec"
    try:
        endpoint = f"tcp://127.0.0.1:{busy.getsockname()[1]}"
        r = _record(endpoint, str(out), "--bind", "--duration", "5")
    finally:
        busy.close()
    assert r.returncode == 2 and f"cannot bind {endpoint!r}" in r.stderr, r.stderr
    assert not out.exists(), "a failed bind left a file behind"
    with LoopbackPublisher(kind="clean", rate_hz=300) as lp:  # the rerun records, no "exists; pass --overwrite"
        r = _record(lp.endpoint, str(out), "--topic", "clean", "--count", "5", "--duration", "30")
    assert r.returncode == 0, r.stderr
    assert read_motion(out).n_frames == 5


def test_overwrite_replaces_the_recording_once_it_has_data(old_recording, tmp_path):
    path, before = old_recording
    with LoopbackPublisher(kind="clean", rate_hz=300) as lp:
        r = _record(lp.endpoint, str(path), "--overwrite", "--topic", "clean", "--count", "20", "--duration", "30")
    assert r.returncode == 0, r.stderr
    assert read_motion(path).n_frames == 20 and path.read_bytes() != before
    assert _names(tmp_path) == ["take.sfrec"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGKILL], ids=["SIGINT", "SIGKILL"])
def test_overwrite_stopped_mid_stream_leaves_every_acknowledged_frame_in_out(old_recording, tmp_path, signum):
    """Ctrl-C: exit 0 with a complete file; SIGKILL: every acknowledged frame readable (the crash-safety promise)."""
    path, _ = old_recording
    with LoopbackPublisher(kind="raw", rate_hz=300) as lp:
        proc = _start(lp.endpoint, str(path), "--overwrite", "--ack", "--topic", "raw", "--fsync", "3600")
        try:
            acks = _read_acks(proc, 90, timeout_s=30)  # >= 0.3 s at 300 Hz: a skeleton message (every 0.2 s) too
            assert len(acks) >= 90, proc.stderr.read().decode() if proc.poll() is not None else "no acks"
            proc.send_signal(signum)
            _, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    frames, meta = read_recording_frames(path)
    assert {seq for _, seq in acks} <= {f.seq for f in frames}, "an acknowledged frame is not in OUT"
    assert "kinect0" in meta["skeletons"] and meta["corrupt_records"] == 0
    if signum == signal.SIGINT:
        assert proc.returncode == 0, err
        assert scan_recording(path).complete
        assert _names(tmp_path) == ["take.sfrec"]
    else:
        assert proc.returncode == -signal.SIGKILL


def test_a_write_that_fails_before_any_record_keeps_the_old_recording(old_recording, tmp_path):
    """A full disk (a file size limit: write(2) fails with EFBIG) at the first record of an
    --overwrite: exit 1 saying so, and the old recording is still there, whole."""
    path, before = old_recording
    limit = 64  # room for the new file's header, not for its first record
    with LoopbackPublisher(kind="clean", rate_hz=300) as lp:
        r = _record(lp.endpoint, str(path), "--overwrite", "--topic", "clean", "--duration", "30",
                    preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    assert r.returncode == 1, r.stderr
    assert "File too large" in r.stderr and "left as it was" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert path.read_bytes() == before
    assert _names(tmp_path) == ["take.sfrec"]


_STOPS = [
    ("--count", "0", "argument --count: must be an integer >= 1, got 0"),
    ("--count", "-1", "argument --count: must be an integer >= 1, got -1"),
    ("--duration", "-1", "must be a number of seconds > 0, got -1"),
    ("--duration", "0", "must be a number of seconds > 0, got 0"),
    ("--duration", "nan", "must be a number of seconds > 0, got nan"),
]
_FSYNC = [
    ("--fsync", "-1", "argument --fsync: must be a number of seconds >= 0 (0 = every record), got -1"),
    ("--fsync", "nan", "argument --fsync: must be a number of seconds >= 0 (0 = every record), got nan"),
]


@pytest.mark.parametrize("command, option, value, message",
                         [("record", *c) for c in _STOPS + _FSYNC] + [("tap", *c) for c in _STOPS])
def test_numbers_that_would_stop_at_once_are_refused(tmp_path, capsys, command, option, value, message):
    out = tmp_path / "r.sfrec"
    argv = ["record", "tcp://127.0.0.1:1", str(out)] if command == "record" else ["tap", "tcp://127.0.0.1:1"]
    with pytest.raises(SystemExit) as exc:  # the parser refuses it, naming the flag
        main([*argv, option, value])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"streamfix {command}: error:" in err and option in err and message in err
    assert not out.exists()


def test_a_recorder_that_got_no_frame_says_so_and_leaves_no_empty_recording(old_recording, tmp_path):
    # nothing publishes on this port: --duration ends the run with no frame in the file
    new = tmp_path / "new.sfrec"
    r = _record("tcp://127.0.0.1:9", str(new), "--duration", "1")
    assert r.returncode == 1 and "no frame received" in r.stderr and "it was not created" in r.stderr, r.stderr
    assert not new.exists()
    path, before = old_recording
    r = _record("tcp://127.0.0.1:9", str(path), "--overwrite", "--duration", "1")
    assert r.returncode == 1 and f"{path} is left as it was" in r.stderr, r.stderr
    assert path.read_bytes() == before and _names(tmp_path) == ["take.sfrec"]
