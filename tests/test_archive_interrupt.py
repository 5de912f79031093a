"""Ctrl-C on ``streamfix clean DIR OUT_DIR --jobs 2`` stops at once and leaves nothing behind.

A real folder of Kinect v2 takes (copies of ``shared/data/kinect_v2/Ges*.csv``), the real
command in a subprocess, a real SIGINT once the first file is reported: the command exits
130 within a bounded time, files not started are not cleaned (the pool is not drained),
no worker process survives, and OUT_DIR holds only complete outputs (no ``.part`` files).
The old code waited for every queued file on Ctrl-C, and now and then forever on an idle worker.

Also: the JSON summary's folder is checked before any cleaning, and a late failure to
write it names the path the user gave, not the temporary file.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from streamfix.archive import write_summary
from streamfix.cli import main
from streamfix.io import read_motion

from test_e2e_harness import PROJECT_ROOT, child_env

COPIES = 10  # of each of the 4 gesture takes: far more work than the few seconds the test waits


def _takes(shared_data: Path, folder: Path) -> list[Path]:
    """COPIES copies of each real Kinect v2 gesture take in ``folder``."""
    folder.mkdir(parents=True)
    paths = []
    for src in sorted((shared_data / "kinect_v2").glob("Ges*.csv")):
        for k in range(COPIES):
            dst = folder / f"{src.stem}_{k:02d}.csv"
            shutil.copy(src, dst)
            paths.append(dst)
    return paths


def _children(pid: int) -> dict[int, str]:
    """The live child processes of ``pid`` and their command lines."""
    kids = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids.update({int(c): "" for c in (task / "children").read_text().split()})
        except OSError:
            continue
    for kid in kids:
        try:
            kids[kid] = Path(f"/proc/{kid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            pass
    return kids


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("target", ["main", "group"], ids=["sigint_to_main", "ctrl_c_to_process_group"])
def test_sigint_stops_a_jobs_2_run_promptly_with_no_worker_left(shared_data, tmp_path, target):
    takes = _takes(shared_data, tmp_path / "in")
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "streamfix", "clean", str(tmp_path / "in"), str(out), "--jobs", "2"],
        stderr=subprocess.PIPE, text=True, env=child_env(), cwd=str(PROJECT_ROOT), start_new_session=True)
    workers: dict[int, str] = {}
    watchdog = threading.Timer(180, lambda: os.killpg(proc.pid, signal.SIGKILL))  # never block the suite
    watchdog.start()
    try:
        lines = []  # until "[1/40] ...: ok": the pool is up and working
        while not (lines and lines[-1].startswith("[1/")):
            lines.append(proc.stderr.readline())
            assert lines[-1], "".join(lines)  # the command ended before the first file
        workers = {k: c for k, c in _children(proc.pid).items() if "multiprocessing" in c and "fork" in c}
        assert len(workers) == 2, workers
        if target == "main":
            proc.send_signal(signal.SIGINT)
        else:  # a terminal's Ctrl-C: the main process and its workers all get SIGINT
            os.killpg(proc.pid, signal.SIGINT)
        t0 = time.monotonic()
        _, err = proc.communicate(timeout=30)
        elapsed = time.monotonic() - t0
    finally:
        watchdog.cancel()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        for pid in workers:  # never leave a worker behind, even when the test fails
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "streamfix: interrupted" in err and "Traceback" not in err, err
    assert elapsed < 20, f"took {elapsed:.1f} s to stop"
    deadline = time.monotonic() + 5
    while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [pid for pid in workers if _alive(pid)], "a worker process survived"
    written = sorted(p.name for p in out.iterdir())
    assert not [n for n in written if n.startswith(".") or ".part" in n], written  # no partial files
    assert len(written) < len(takes), "the queued files were cleaned after Ctrl-C instead of cancelled"
    for name in written:  # what is there is complete
        assert read_motion(out / name).n_frames > 100, name


def test_summary_in_a_missing_folder_is_refused_before_any_cleaning(shared_data, tmp_path, capsys):
    (tmp_path / "in").mkdir()
    shutil.copy(shared_data / "kinect_v2" / "Ges01_wavehand.csv", tmp_path / "in" / "take.csv")
    summary = tmp_path / "nonexist" / "s.json"
    out = tmp_path / "out"
    assert main(["clean", str(tmp_path / "in"), str(out), "--summary", str(summary)]) == 2
    err = capsys.readouterr().err
    assert f"--summary {summary}" in err and "does not exist" in err and ".part" not in err, err
    assert "[1/1]" not in err and not out.exists()  # nothing cleaned, no empty OUT left behind
    # a summary inside OUT (which the run creates) is fine
    assert main(["clean", str(tmp_path / "in"), str(out), "--summary", str(out / "s.json"), "--quiet"]) == 0
    assert (out / "s.json").is_file() and (out / "take.csv").is_file()


def test_a_summary_that_cannot_be_written_names_the_users_path(tmp_path):
    records = [{"input": "a.csv", "output": "o/a.csv", "status": "ok", "error": None, "frames": 3, "seconds": 0.1}]
    target = tmp_path / "gone" / "s.json"  # its folder vanished after the up-front check
    with pytest.raises(OSError) as info:
        write_summary(records, target)
    assert str(target) in str(info.value) and ".part" not in str(info.value)
    write_summary(records, tmp_path / "s.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]  # no temporary file left


@pytest.mark.parametrize("archive", [False, True], ids=["one_file", "folder"])
def test_a_missing_training_path_is_an_error_not_ignored(shared_data, tmp_path, capsys, archive):
    """A Kinect take (a skeleton with bones: the takes go unused, with a note) and a C3D marker
    take without gaps (the gap filler never reads them): both once ignored a mistyped --training."""
    (tmp_path / "in").mkdir()
    shutil.copy(shared_data / "c3d" / "85_02.c3d", tmp_path / "in" / "markers.c3d")
    assert read_motion(tmp_path / "in" / "markers.c3d").observed.all()
    shutil.copy(shared_data / "kinect_v2" / "Ges01_wavehand.csv", tmp_path / "in" / "take.csv")
    missing = tmp_path / "nonexist"
    inputs = [str(tmp_path / "in")] if archive else [str(tmp_path / "in" / "take.csv"),
                                                      str(tmp_path / "in" / "markers.c3d")]
    for src in inputs:
        out = tmp_path / ("out" if archive else f"out{Path(src).suffix}")
        assert main(["clean", src, str(out), "--training", str(missing)]) == 2
        err = capsys.readouterr().err
        assert f"--training {missing}" in err and "not found" in err, err
        assert not out.exists()
    if not archive:  # an existing path on a skeleton with bones: cleaned, with the note that it went unused
        ok = main(["clean", inputs[0], str(tmp_path / "ok.csv"), "--training", str(tmp_path / "in" / "markers.c3d")])
        assert ok == 0
        assert "reference takes unused" in capsys.readouterr().out
