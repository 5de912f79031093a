"""The file-writing commands never lose data silently (issue 10).

``clean`` checks its output before solving (missing directory, own input, existing
file without ``--overwrite``) and exits non-zero when the writer fails; ``record``
writes only ``.sfrec`` and, when the disk fills (here: a file size limit, which makes
``write(2)`` fail the same way), prints one line, exits 1 and leaves a readable file
holding every acknowledged frame; ``replay`` with nobody listening says so and exits 1.
"""
from __future__ import annotations

import resource
import shutil
import subprocess
import sys
import time

import numpy as np
import zmq

from streamfix.cli import main
from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io.recording import read_recording_frames
from streamfix.transport.wire import encode_frame, topic_for

from test_e2e_harness import PROJECT_ROOT, child_env, connect_and_wait, free_port


def _cli(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamfix", *args], capture_output=True, text=True,
                          timeout=timeout, env=child_env(), cwd=str(PROJECT_ROOT), **kw)


def test_clean_checks_its_output_before_solving_and_never_overwrites_its_input(tmp_path, shared_data, capsys,
                                                                             monkeypatch):
    import streamfix.cleaning

    src = tmp_path / "in.csv"
    shutil.copy(shared_data / "kinect_v2" / "Ges01_wavehand.csv", src)
    before = src.read_bytes()

    def solved(*args, **kwargs):
        raise AssertionError("clean solved before refusing its output")

    with monkeypatch.context() as patch:
        patch.setattr(streamfix.cleaning, "clean_recording", solved)
        for out, expect in ((tmp_path / "missing" / "out.c3d", "does not exist"),
                            (src, "refusing to overwrite the input"),
                            (tmp_path / "." / "in.csv", "refusing to overwrite the input"),
                            (tmp_path / "out.txt", "must end in")):
            assert main(["clean", str(src), str(out)]) == 2, out
            got = capsys.readouterr()
            assert expect in got.err and got.out == "", (out, got)
    assert src.read_bytes() == before
    existing = tmp_path / "out.csv"
    existing.write_text("keep me\n")
    assert main(["clean", str(src), str(existing)]) == 2
    assert "--overwrite" in capsys.readouterr().err and existing.read_text() == "keep me\n"


def test_clean_exits_non_zero_when_the_writer_fails(tmp_path, shared_data):
    src = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    out = tmp_path / "out.sfrec"
    limit = 4096  # the file may not grow past 4 kB: write(2) fails like on a full disk
    r = _cli("clean", str(src), str(out), "--quiet",
             preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    assert r.returncode == 1, r.stderr
    assert "cannot write" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_record_refuses_other_formats_and_survives_a_full_disk_with_a_readable_file(tmp_path):
    r = _cli("record", "tcp://127.0.0.1:1", str(tmp_path / "x.csv"), "--duration", "1")
    assert r.returncode == 2 and ".sfrec" in r.stderr and not (tmp_path / "x.csv").exists()

    port = free_port()
    out = tmp_path / "full.sfrec"
    limit = 20_000
    proc = subprocess.Popen(
        [sys.executable, "-m", "streamfix", "record", f"tcp://127.0.0.1:{port}", str(out), "--bind", "--ack",
         "--duration", "60", "--fsync", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env(), cwd=str(PROJECT_ROOT),
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    try:
        connect_and_wait(push, f"tcp://127.0.0.1:{port}", timeout=30)
        J = 25
        for seq in range(200):
            frame = SkeletonFrame("disk", seq, seq * 33_333_333, "kinect_v2",
                                  [BodyFrame(0, np.full((J, 3), 0.1 * seq), np.ones(J))])
            push.send_multipart([topic_for("raw", "disk"), encode_frame(frame)])
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        push.close(linger=0)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, stderr
    errors = [ln for ln in stderr.splitlines() if "writing" in ln]
    assert len(errors) == 1 and "File too large" in errors[0], stderr
    assert "Traceback" not in stderr
    acked = [int(line.split()[-1]) for line in stdout.splitlines() if line.startswith("ack ")]
    assert 10 < len(acked) < 200
    frames, _ = read_recording_frames(out)
    assert [f.seq for f in frames] == acked, "the file holds exactly the acknowledged frames"


def test_replay_with_nobody_listening_says_so_and_fails(shared_data):
    t0 = time.monotonic()
    r = _cli("replay", str(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), "--to",
             f"tcp://127.0.0.1:{free_port()}", "--speed", "0", "--timeout", "1", "--wait", "1")
    assert r.returncode == 1 and "no receiver" in r.stderr, r.stderr
    assert "sent 154 frames" not in r.stderr
    assert time.monotonic() - t0 < 30


def test_clean_interrupted_while_writing_leaves_the_old_output_whole(shared_data, tmp_path, monkeypatch):
    # the output is written beside OUT and renamed: a Ctrl-C (or a crash) mid-write never leaves half a file
    import streamfix.io
    from streamfix.cli import main

    out = tmp_path / "wave.clean.csv"
    out.write_text("the previous cleaning\n")

    def torn_write(motion, path, *a, **kw):
        with open(path, "w") as f:
            f.write("half a fi")
        raise KeyboardInterrupt

    monkeypatch.setattr(streamfix.io, "write_motion", torn_write)
    code = main(["clean", str(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), str(out), "--overwrite", "--quiet"])
    assert code == 130
    assert out.read_text() == "the previous cleaning\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wave.clean.csv"], "no partial file left behind"
