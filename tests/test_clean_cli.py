"""``streamfix clean IN OUT``: real files in, readable files out, same engine as serve."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from streamfix.cli import main
from streamfix.io import read_motion
from streamfix.streaming.engine import EngineConfig
from streamfix.streaming.offline import clean_motion


@pytest.mark.parametrize("name", ["Ges01_wavehand.csv", "seated_joints.csv"])
def test_clean_kinect_file_writes_readable_file_with_same_frames(shared_data, tmp_path, capsys, name):
    src = shared_data / "kinect_v2" / name
    out = tmp_path / "clean.csv"
    assert main(["clean", str(src), str(out)]) == 0
    summary = capsys.readouterr().out.strip().splitlines()
    assert len(summary) == 1 and "frames" in summary[0] and "recovered" in summary[0] and "mm" in summary[0]
    a, b = read_motion(src), read_motion(out)
    assert b.n_frames == a.n_frames and b.n_joints == a.n_joints
    np.testing.assert_allclose(b.timestamps, a.timestamps, atol=1e-6)
    assert np.isfinite(b.positions).all()  # nothing left missing
    change = np.linalg.norm(b.positions - a.positions, axis=2)[a.observed]
    assert 0 < np.median(change) < 0.05  # cleaned, not replaced
    # the file is what the engine emits on clean on the file schedule (within the CSV's 9 digits)
    expect, _ = clean_motion(a, EngineConfig.for_files(a.rate_hz))
    np.testing.assert_allclose(b.positions, expect.positions, atol=1e-6)
    # and with --schedule serve, what serve publishes on its clean topic
    served = tmp_path / "served.csv"
    assert main(["clean", str(src), str(served), "--schedule", "serve", "--quiet"]) == 0
    topic, _ = clean_motion(a, EngineConfig(rate_hz=a.rate_hz))
    np.testing.assert_allclose(read_motion(served).positions, topic.positions, atol=1e-6)
    assert np.abs(topic.positions - expect.positions).max() > 1e-3  # the two schedules differ


def test_clean_rejects_wrong_number_of_skeleton_lengths(shared_data, tmp_path, capsys):
    src = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    code = main(["clean", str(src), str(tmp_path / "x.csv"), "--skeleton-lengths", "0.1,0.2"])
    assert code == 2
    assert "24 bones" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_clean_with_fixed_skeleton_lengths_keeps_them(shared_data, tmp_path):
    src = shared_data / "kinect_v2" / "Ges02_balancinghands.csv"
    a = read_motion(src)
    bones = a.skeleton.bone_array
    lengths = np.nanmedian(np.linalg.norm(a.positions[:, bones[:, 1]] - a.positions[:, bones[:, 0]], axis=2), axis=0)
    lfile = tmp_path / "lengths.txt"
    lfile.write_text("\n".join(f"{v:.6f}" for v in lengths))
    out = tmp_path / "c.csv"
    assert main(["clean", str(src), str(out), "--skeleton-lengths", str(lfile), "--quiet"]) == 0
    b = read_motion(out)
    got = np.linalg.norm(b.positions[:, bones[:, 1]] - b.positions[:, bones[:, 0]], axis=2)
    cv_in = np.nanstd(np.linalg.norm(a.positions[:, bones[:, 1]] - a.positions[:, bones[:, 0]], axis=2), axis=0)
    assert np.mean(np.std(got, axis=0)) < np.mean(cv_in)  # bone lengths steadier than the input's
    # and held: the length play tracked bones keep otherwise (0.9 mm on average here) is off
    assert np.nanmean(np.abs(got - lengths[None, :])) < 0.0005


def test_clean_bvh_to_recording_and_bad_input(shared_data, tmp_path):
    src = shared_data / "xia_bvh" / "depressed_18_000.bvh"
    out = tmp_path / "c.sfrec"
    proc = subprocess.run(
        [sys.executable, "-m", "streamfix", "clean", str(src), str(out), "--window", "120", "--hop", "20",
         "--lookahead", "30f"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # no progress bar when stderr is not a terminal
    a, b = read_motion(src), read_motion(out)
    assert b.n_frames == a.n_frames and b.n_joints == a.n_joints
    assert np.abs(b.positions - a.positions).max() < 0.05  # clean mocap stays where it was
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n")
    proc = subprocess.run([sys.executable, "-m", "streamfix", "clean", str(bad), str(tmp_path / "o.csv")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "bad.csv" in proc.stderr


def _failing_solver(every: int):
    """A window solver that raises like a broken installation on every ``every``-th window
    and otherwise returns its input (the engine's clean output is then the input)."""
    from streamfix.streaming.engine import WindowOutput

    calls = [0]

    def solve(positions, confidence, bones, lengths, rate_hz, **kwargs):
        calls[0] += 1
        if calls[0] % every == 0:
            raise ModuleNotFoundError("No module named 'pywt'")
        return WindowOutput(positions.copy(), np.zeros(positions.shape[:2], dtype=bool), None, 1, True)

    return solve


def test_clean_reads_a_nan_joint_as_missing_and_says_so(shared_data, tmp_path, capsys):
    """A tracked joint with a NaN coordinate is missing for that frame: the file is cleaned
    (every frame out, the joint recovered there) and the warning says how many there were."""
    lines = (shared_data / "kinect_v2" / "Ges01_wavehand.csv").read_text().splitlines()
    parts = lines[40].split(",")
    parts[1 + 4 * 9: 1 + 4 * 9 + 3] = ["nan", "nan", "nan"]  # WristRight, trackingState left at 2
    lines[40] = ",".join(parts)
    src = tmp_path / "nan_wrist.csv"
    src.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.csv"
    assert main(["clean", str(src), str(out), "--quiet"]) == 0
    assert "1 joint-sample(s) flagged seen but with a NaN/inf coordinate, read as missing" in capsys.readouterr().err
    cleaned = read_motion(out)
    assert cleaned.n_frames == len(lines) and np.isfinite(cleaned.positions[40, 9]).all()


def test_clean_fails_loudly_when_no_window_solves(shared_data, tmp_path, capsys, monkeypatch):
    """A broken solver must not pass the live path's output off as a cleaning."""
    import streamfix.streaming.engine as engine

    monkeypatch.setattr(engine, "default_window_solver", lambda: _failing_solver(1))
    out = tmp_path / "clean.csv"
    assert main(["clean", str(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), str(out)]) == 1
    err = capsys.readouterr().err
    assert "every window solve failed" in err and "No module named 'pywt'" in err
    assert not out.exists()


def test_clean_reports_windows_that_failed_and_keeps_every_frame(shared_data, tmp_path, capsys, monkeypatch):
    import streamfix.streaming.engine as engine

    monkeypatch.setattr(engine, "default_window_solver", lambda: _failing_solver(3))
    src = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    out = tmp_path / "clean.csv"
    # 3 s windows every 4/3 s: the 5 s take has several windows (the file schedule's 10 s: one)
    assert main(["clean", str(src), str(out), "--quiet", "--window", "90", "--hop", "40", "--lookahead", "2s"]) == 0
    err = capsys.readouterr().err
    assert "window(s) failed to solve" in err and "No module named 'pywt'" in err
    a, b = read_motion(src), read_motion(out)
    assert b.n_frames == a.n_frames and np.isfinite(b.positions).all()


def test_an_unimportable_solver_stops_clean_and_serve_with_the_reason(shared_data, tmp_path, capsys, monkeypatch):
    """A missing dependency (here the solver module itself) must not leave ``clean`` or
    ``serve`` running the live path and calling it clean."""
    from streamfix.streaming.solver_api import WindowSolverError
    from streamfix.streaming.window_solvers import default_window_solver

    monkeypatch.setitem(sys.modules, "streamfix.core.pipeline", None)  # import fails as if a dependency were missing
    with pytest.raises(WindowSolverError, match="cannot be imported"):
        default_window_solver()
    out = tmp_path / "clean.csv"
    assert main(["clean", str(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), str(out)]) == 1
    assert "window solver cannot be imported" in capsys.readouterr().err and not out.exists()
    from test_e2e_harness import free_port

    src = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    assert main(["serve", "--source", f"replay:{src}", "--out", f"tcp://127.0.0.1:{free_port()}"]) == 2
    assert "cannot start the engine: the window solver cannot be imported" in capsys.readouterr().err
