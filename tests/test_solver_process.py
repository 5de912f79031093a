"""The process-backed window solver (streamfix/streaming/solver_process.py): real child
processes, a real recording, a real ``serve``.

Its promise is the in-thread solver's output exactly (one child serves one engine's calls
in order, the warm-start state travels with each window), and a child that dies or stalls
costs one counted window, never a frame or a hung engine.
"""
from __future__ import annotations

import copy
import os
import signal
import time

import numpy as np
import pytest
import zmq

from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.streaming.config import EngineConfig
from streamfix.streaming.engine import StreamEngine
from streamfix.streaming.offline import clean_motion, motion_frames
from streamfix.streaming.solver_process import ProcessWindowSolver, SolverProcessError
from streamfix.streaming.window_solvers import default_window_solver, wants
from streamfix.transport.wire import encode_frame, encode_skeleton_message, topic_for

from test_e2e_harness import connect_and_wait, connected_subscriber, serve, wait_metric


@pytest.fixture(scope="module")
def seated(shared_data):
    return read_kinect_csv(shared_data / "kinect_v2" / "seated_joints.csv")


def _wait_dead(pid: int, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(") ", 1)[1].startswith("Z"):
                    return  # a zombie: dead, not yet reaped by its parent (the forkserver)
        except (FileNotFoundError, ProcessLookupError):  # gone, or reaped between open and read
            return
        time.sleep(0.01)
    raise AssertionError(f"process {pid} still alive after {timeout} s")


def test_clean_output_with_the_solver_process_equals_the_in_thread_solver(seated):
    # the recording as it is, and with the left arm lost for 3 s (after 7 s of history): the
    # bridge then fills it by PCA on the body's clean history, which must reach the child
    gapped = copy.deepcopy(seated)
    arm = [seated.skeleton.index(j) for j in ("ElbowLeft", "WristLeft", "HandLeft")]
    gapped.positions[210:300, arm] = np.nan
    gapped.confidence[210:300, arm] = 0.0
    with ProcessWindowSolver() as solver:
        assert wants(solver, "wants_history") and wants(solver, "wants_skeleton")
        for motion in (seated, gapped):
            expected, m_thread = clean_motion(motion)
            got, m_proc = clean_motion(motion, window_solver=solver)
            assert np.array_equal(got.positions, expected.positions, equal_nan=True)
            assert np.array_equal(got.recovered, expected.recovered)
            assert np.array_equal(got.confidence, expected.confidence)
            for key in ("windows_solved", "solver_iterations", "solver_errors", "joints_recovered",
                        "joints_bridged_pca", "joints_bridged_prior", "joints_bridged_hold", "clean_out"):
                assert m_proc[key] == m_thread[key], key
            assert m_proc["solver_errors"] == 0 and m_proc["windows_solved"] > 30
    assert m_proc["joints_bridged_pca"] > 0  # the gapped run: filled from the history


def test_a_killed_child_costs_one_window_and_no_frame(seated):
    solver = ProcessWindowSolver()
    engine = StreamEngine(seated.skeleton, EngineConfig(rate_hz=seated.rate_hz, threaded=False), solver)
    frames = list(motion_frames(seated))
    clean = []
    for i, frame in enumerate(frames):
        if i == 150:  # mid-run, between two windows: the next window finds its child dead
            first = solver.pid
            os.kill(first, signal.SIGKILL)
            _wait_dead(first)
            solved = engine.counters["windows_solved"]
        clean += [out for kind, out in engine.push(frame) if kind == "clean"]
    clean += [out for kind, out in engine.flush() if kind == "clean"]
    m = engine.metrics()
    engine.close()
    assert m["solver_errors"] == 1
    assert solver.restarts == 1 and solver.pid is None  # closed with the engine
    assert m["windows_solved"] > solved + 3  # the windows after the failed one were solved
    assert m["windows_solved"] + m["solver_errors"] + m["windows_skipped"] == m["windows_scheduled"]
    assert len(clean) == m["clean_out"]
    assert sum(not f.filled for f in clean) == len(frames)  # every input frame (the recording has 2 drops filled)


def test_a_stalled_window_times_out_and_the_next_one_is_solved_by_a_new_child(seated):
    sk = seated.skeleton
    x, c = seated.positions[:60], seated.confidence[:60]
    expected = default_window_solver()(x, c, sk.bone_array, None, seated.rate_hz, skeleton=sk)
    with ProcessWindowSolver(timeout_s=1e-4) as solver:  # no window takes 0.1 ms
        solver.wait_ready()
        first = solver.pid
        with pytest.raises(SolverProcessError, match="did not answer within"):
            solver(x, c, sk.bone_array, None, seated.rate_hz, skeleton=sk)
        _wait_dead(first)  # the stalled child was stopped
        solver.timeout_s = 5.0
        res = solver(x, c, sk.bone_array, None, seated.rate_hz, skeleton=sk)
        assert solver.pid != first and solver.restarts == 1
    assert np.array_equal(res.positions, expected.positions)
    assert np.array_equal(res.recovered, expected.recovered)


def test_a_solver_exception_fails_the_window_and_keeps_the_child(seated):
    sk = seated.skeleton
    with ProcessWindowSolver() as solver:
        solver.wait_ready()
        pid = solver.pid
        with pytest.raises(SolverProcessError, match="ValueError|IndexError"):
            solver(seated.positions[:60], seated.confidence[:60, :3], sk.bone_array, None, seated.rate_hz)
        assert solver.pid == pid and solver.restarts == 0


def _children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid``, from /proc."""
    found = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    if int(f.read().rsplit(") ", 1)[1].split()[1]) == pid:
                        found.add(int(entry))
            except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
                pass
    return found


def test_serve_with_solver_processes_survives_a_killed_child_without_losing_a_frame(tmp_path, seated):
    """A real ``serve --solver-process``: one stream at 30 Hz; its solver child is killed mid-stream.
    No frame is shed at the stream's start (the child was warm before the first frame), every frame
    comes out on ``clean``, the dead child's window is one counted solver error."""
    n, kill_at = 120, 60
    with serve(tmp_path, "--sndhwm", "0", "--idle-timeout", "0", "--overload", "shed", "--solver-process") as sp:
        sub = connected_subscriber(sp.out, (b"sf/clean/",))
        push = zmq.Context.instance().socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 0)
        try:
            connect_and_wait(push, sp.source)
            push.send_multipart([topic_for("meta", "s"), encode_skeleton_message(seated.skeleton, 30.0, "s")])
            t0 = time.monotonic()
            for k, frame in enumerate(motion_frames(seated, stream_id="s")):
                if k == n:
                    break
                if k == kill_at:
                    # serve's children: the forkserver, multiprocessing's resource tracker;
                    # the forkserver's: the stream's solver child
                    workers = [c for p in _children(sp.proc.pid) for c in _children(p)]
                    assert len(workers) == 1, workers
                    os.kill(workers[0], signal.SIGKILL)
                push.send_multipart([topic_for("raw", "s"), encode_frame(frame)])
                time.sleep(max(0.0, t0 + (k + 1) / 30.0 - time.monotonic()))
            m = wait_metric(sp, 'streamfix_frames_in_total{stream="s"}', n)
            assert sp.terminate() == 0, sp.stderr[-2000:]  # flushes the stream: its last frames come out
            clean = [r.message for r in sub.receive(timeout_s=2.0)]
        finally:
            push.close(linger=0)
            sub.close()
    assert m.get('streamfix_shed_frames_total{reason="backlog"}', 0.0) == 0, sp.stderr[-2000:]
    assert m['streamfix_engine_events_total{event="solver_errors"}'] == 1, sp.stderr[-2000:]
    assert m['streamfix_engine_events_total{event="windows_solved"}'] > 5
    assert sum(not f.filled for f in clean) == n, sp.stderr[-2000:]
