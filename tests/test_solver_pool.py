"""The process-wide pool of window-solver threads (streamfix.streaming.solver_pool)."""
from __future__ import annotations

import itertools
import os
import threading

import numpy as np

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.skeletons import KINECT_V2
from streamfix.streaming import engine as engine_module
from streamfix.streaming.engine import EngineConfig, StreamEngine, ThreadedStreamEngine, WindowOutput
from streamfix.streaming.solver_pool import SOLVER_NICE, SolverPool, pool_size, shared_pool

NS = 1_000_000_000


def test_one_thread_runs_tasks_in_the_order_they_were_submitted():
    pool = SolverPool(1)
    gate, done = threading.Event(), threading.Event()
    order: list[int] = []
    pool.submit(gate.wait)  # hold the thread while the queue fills
    for i in range(20):
        pool.submit(lambda i=i: order.append(i))
    pool.submit(done.set)
    gate.set()
    assert done.wait(10)
    assert order == list(range(20))


def test_the_shared_pool_is_one_per_process_with_a_thread_per_cpu():
    assert shared_pool() is shared_pool()
    assert shared_pool().threads == pool_size() == len(os.sched_getaffinity(0))


class RecordingSolver:
    """Identity windows; records the thread each window was solved on."""

    def __init__(self):
        self.threads: set[str] = set()
        self.calls = 0

    def __call__(self, positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
        self.calls += 1
        self.threads.add(threading.current_thread().name)
        return WindowOutput(positions.copy(), ~(confidence > 0), None, 1, True)


def _frames(n, stream, rng):
    base = rng.normal(0.0, 0.3, (KINECT_V2.n_joints, 3))
    for i in range(n):
        yield SkeletonFrame(stream, i, i * NS // 30, KINECT_V2.name,
                            [BodyFrame(1, base + 0.01 * np.sin(i / 5.0), np.ones(KINECT_V2.n_joints))])


def test_engines_share_the_pool_and_give_the_synchronous_output():
    """Five threaded engines (serve's engine per stream) use the pool's threads, not one
    thread each, and each one's clean output equals the synchronous engine's."""
    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    rng = np.random.default_rng(3)
    streams = [list(_frames(120, f"s{k}", rng)) for k in range(5)]
    solvers = [RecordingSolver() for _ in streams]
    engines = [ThreadedStreamEngine(KINECT_V2, cfg, s) for s in solvers]
    first = shared_pool().body_ordinals_issued  # the engines' bodies take the next five, in push order
    outs: list[list] = [[] for _ in streams]
    for i in range(120):  # interleaved, as serve receives them
        for k, eng in enumerate(engines):
            outs[k] += eng.push(streams[k][i]) + eng.poll()
    for k, eng in enumerate(engines):
        outs[k] += eng.flush()
        eng.close()
    names = set().union(*(s.threads for s in solvers))
    assert names <= {f"streamfix-solver-{i}" for i in range(pool_size())}, names
    for k, frames in enumerate(streams):
        # the same window phase as the threaded engine's body (its ordinal in the pool)
        sync = StreamEngine(KINECT_V2, cfg, RecordingSolver(), body_ordinals=itertools.count(first + k).__next__)
        expected = [f for kind, f in [x for fr in frames for x in sync.push(fr)] + sync.flush() if kind == "clean"]
        got = [f for kind, f in outs[k] if kind == "clean"]
        assert [f.seq for f in got] == [f.seq for f in expected]
        assert np.array_equal(np.stack([f.bodies[0].positions for f in got]),
                              np.stack([f.bodies[0].positions for f in expected]))


def test_bodies_of_engines_sharing_the_pool_fall_due_on_different_frames(monkeypatch):
    """serve runs an engine per stream: the k-th body of every stream must not get the same
    window phase, or their windows all fall due on one frame and the last waits for the
    others (clean delay). The pool numbers the bodies of all its engines together; a
    synchronous engine numbers its own from 0, so offline output does not depend on what
    else the process runs."""
    from streamfix.streaming.bodies import hop_phase

    pool = SolverPool(1)
    monkeypatch.setattr(engine_module, "shared_pool", lambda: pool)
    cfg = EngineConfig(rate_hz=30.0)
    rng = np.random.default_rng(5)
    engines = [ThreadedStreamEngine(KINECT_V2, cfg, RecordingSolver()) for _ in range(5)]
    for k, eng in enumerate(engines):
        eng.push(next(_frames(1, f"s{k}", rng)))
    phases = [next(iter(eng.streams.values())).bodies[1].phase for eng in engines]
    assert phases == [hop_phase(k, cfg.hop) for k in range(5)]
    assert len(set(phases)) == 5 and pool.body_ordinals_issued == 5
    for eng in engines:
        eng.close()
    sync = [StreamEngine(KINECT_V2, cfg, RecordingSolver()) for _ in range(2)]
    for k, eng in enumerate(sync):
        eng.push(next(_frames(1, f"s{k}", rng)))
    assert [next(iter(eng.streams.values())).bodies[1].phase for eng in sync] == [0, 0]


def test_an_engine_tells_its_listener_when_a_window_is_done():
    """The service wakes its loop on this (the clean frames go out at once, not at the
    loop's next turn): called from the pool's thread once per finished window."""
    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    eng = ThreadedStreamEngine(KINECT_V2, cfg, RecordingSolver())
    calls: list[str] = []
    eng.on_window_done = lambda: calls.append(threading.current_thread().name)
    for f in _frames(60, "w", np.random.default_rng(6)):
        eng.push(f)
    eng.flush(timeout=30)
    eng.close()
    assert len(calls) == eng.metrics()["windows_scheduled"] > 0
    assert all(name.startswith("streamfix-solver-") for name in calls), calls


def test_a_window_goes_to_the_pool_after_the_frame_that_scheduled_it(monkeypatch):
    """push() defers the windows it schedules; the next poll() (serve calls it after sending
    the frame's live output), push() or flush() submits them: a solve that starts while the
    live frame is still being published slows it down (bench_service, one body)."""
    pool = SolverPool(1)
    submitted: list = []
    real_submit = pool.submit
    monkeypatch.setattr(pool, "submit", lambda task: (submitted.append(task), real_submit(task)))
    monkeypatch.setattr(engine_module, "shared_pool", lambda: pool)
    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    eng = ThreadedStreamEngine(KINECT_V2, cfg, RecordingSolver())
    frames = list(_frames(40, "d", np.random.default_rng(7)))
    scheduled = 0
    for f in frames:
        eng.push(f)
        now = eng.metrics()["windows_scheduled"]
        if now > scheduled:
            assert len(submitted) == scheduled  # not yet: the caller has the live frame to send
            eng.poll()
            assert len(submitted) == now
            scheduled = now
    assert scheduled >= 3
    eng.push(next(_frames(1, "e", np.random.default_rng(8))))  # a caller that never polls:
    out = eng.flush(timeout=30)                                 # push and flush submit too
    eng.close()
    assert len(submitted) == eng.metrics()["windows_scheduled"]
    assert sum(kind == "clean" for kind, _ in out) > 0


def test_a_closed_engine_s_queued_windows_are_not_solved(monkeypatch):
    """Windows still queued when their engine closes are skipped, not solved, and the
    pool goes on with the other engines' windows."""
    pool = SolverPool(1)
    monkeypatch.setattr(engine_module, "shared_pool", lambda: pool)
    gate = threading.Event()
    pool.submit(gate.wait)  # the pool's one thread is busy: windows queue up
    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    rng = np.random.default_rng(4)
    closed_solver, open_solver = RecordingSolver(), RecordingSolver()
    closing = ThreadedStreamEngine(KINECT_V2, cfg, closed_solver)
    staying = ThreadedStreamEngine(KINECT_V2, cfg, open_solver)
    for a, b in zip(_frames(90, "a", rng), _frames(90, "b", rng)):
        closing.push(a)
        staying.push(b)
    assert closing.metrics()["windows_scheduled"] > 0
    closing.close()
    gate.set()
    out = staying.flush(timeout=30)
    staying.close()
    assert closed_solver.calls == 0
    assert open_solver.calls > 0
    assert sum(kind == "clean" for kind, _ in out) == 90


def test_a_task_that_raises_does_not_stop_the_thread():
    pool = SolverPool(1)
    done = threading.Event()

    def broken():
        raise RuntimeError("boom")

    pool.submit(broken)
    pool.submit(done.set)
    assert done.wait(10)


def test_pool_threads_run_below_the_input_threads_priority():
    """A live frame must not wait for a solve's time slice: the solver threads are niced
    (per thread, on Linux), the thread that submits is not."""
    if not hasattr(os, "getpriority"):
        return
    main_nice = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    pool = SolverPool(1)
    seen: list[int] = []
    done = threading.Event()
    pool.submit(lambda: (seen.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id())), done.set()))
    assert done.wait(10)
    assert seen == [min(19, main_nice + SOLVER_NICE)]
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == main_nice


def test_a_threaded_engine_imports_the_solvers_lazy_modules_before_its_first_window():
    """An import inside a window holds the GIL (and the import lock) while the live path
    waits: the threaded engine does them when it starts."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from streamfix.skeletons import KINECT_V2\n"
        "from streamfix.streaming.engine import EngineConfig, ThreadedStreamEngine\n"
        "lazy = ['streamfix.prior.init', 'streamfix.core.dislocated', 'streamfix.core.pca_gapfill']\n"
        "before = [m for m in lazy if m in sys.modules]\n"
        "ThreadedStreamEngine(KINECT_V2, EngineConfig()).close()\n"
        "print(before, [m for m in lazy if m not in sys.modules])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[] []", out.stdout
