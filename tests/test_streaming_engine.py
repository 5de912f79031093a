"""Streaming engine: exactly-once ordered output, overlap-add, drops, bodies, bad input, threads.

Window solvers here are stand-ins with the ``clean_window`` signature, so these tests
check the engine itself: identity (must reproduce the input bit for bit), a constant
offset (the overlap-add weights must sum to 1), a Savitzky-Golay window cleaner, and an
Event-gated one that stalls until the test releases it.
"""
from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest
from scipy.signal import savgol_filter

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.engine import EngineConfig, StreamEngine, ThreadedStreamEngine, WindowOutput

J = KINECT_V2.n_joints
NS = 1_000_000_000


# ----------------------------------------------------------------------------- stand-in solvers
def identity_solver(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
    return WindowOutput(positions.copy(), ~(confidence > 0), None, 1, True)


def offset_solver(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
    return WindowOutput(positions + 0.125, np.zeros(confidence.shape, bool), None, 1, True)


def savgol_solver(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
    """Gaps filled linearly per channel, then a quadratic Savitzky-Golay along time."""
    T = positions.shape[0]
    obs = (confidence > 0) & np.isfinite(positions).all(axis=2)
    x = positions.copy()
    t = np.arange(T)
    for j in np.flatnonzero(~obs.all(axis=0)):  # stand-in: a loop is fine in a test
        if obs[:, j].any():
            for c in range(3):
                x[:, j, c] = np.interp(t, t[obs[:, j]], positions[obs[:, j], j, c])
    n = min(7, T if T % 2 else T - 1)
    if n >= 3:
        x = savgol_filter(x, n, 2, axis=0, mode="interp")
    return WindowOutput(x, ~obs, {"end": T}, 2, True)


# ----------------------------------------------------------------------------- helpers
@pytest.fixture(scope="module")
def kinect(shared_data):
    return read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")


def frames_of(motion, *, uniform=False, seq0=100, body_id=7, stream="k"):
    times = np.arange(motion.n_frames) / motion.rate_hz if uniform else motion.timestamps
    for i in range(motion.n_frames):
        yield SkeletonFrame(
            stream, seq0 + i, int(round(times[i] * NS)), KINECT_V2.name,
            [BodyFrame(body_id, motion.positions[i].copy(), motion.confidence[i].copy())],
        )


def run(engine, frames):
    out = []
    per_push = []
    for f in frames:
        got = engine.push(f)
        per_push.append(got)
        out += got
    out += engine.flush()
    return out, per_push


def run_threaded(engine, frames):
    """The clean frames of a threaded engine fed ``frames`` (polling after each push), closed."""
    out = []
    for f in frames:
        out += engine.push(f)
        out += engine.poll()
    out += engine.flush()
    engine.close()
    return split(out)[1]


def split(out):
    return [f for k, f in out if k == "live"], [f for k, f in out if k == "clean"]


def body_array(frames, body_id=None):
    return np.array([
        next(b for b in f.bodies if body_id is None or b.body_id == body_id).positions for f in frames
    ])


# ----------------------------------------------------------------------------- exactly once, in order
def test_every_frame_once_on_live_and_clean_in_order(kinect):
    cfg = EngineConfig(rate_hz=kinect.rate_hz)
    out, _ = run(StreamEngine(KINECT_V2, cfg, savgol_solver), frames_of(kinect))
    live, clean = split(out)
    # the real recording has timestamp gaps: they come out as filled frames
    n_filled = sum(f.filled for f in clean)
    assert len(live) == len(clean) == kinect.n_frames + n_filled
    for stream in (live, clean):
        seqs = [f.seq for f in stream]
        assert seqs == list(range(100, 100 + len(stream)))  # consecutive, no holes, no repeats
        real_times = [f.sensor_time_ns for f in stream if not f.filled]
        assert real_times == [int(round(t * NS)) for t in kinect.timestamps]
        times = [f.sensor_time_ns for f in stream]
        assert all(b > a for a, b in zip(times, times[1:]))
    assert [f.filled for f in live] == [f.filled for f in clean]
    for f in clean:
        assert np.isfinite(f.bodies[0].positions).all()


def test_clean_is_deterministic(kinect):
    cfg = EngineConfig(rate_hz=kinect.rate_hz, window=50, hop=4, lookahead=12)
    a = split(run(StreamEngine(KINECT_V2, cfg, savgol_solver), frames_of(kinect))[0])[1]
    b = split(run(StreamEngine(KINECT_V2, cfg, savgol_solver), frames_of(kinect))[0])[1]
    assert np.array_equal(body_array(a), body_array(b))
    assert [f.seq for f in a] == [f.seq for f in b]
    # and the clean output really differs from the input (the test can fail)
    real = [f for f in a if not f.filled]
    assert np.abs(body_array(real) - kinect.positions).max() > 1e-3


@pytest.mark.parametrize("W,H,L", [(60, 10, 15), (50, 1, 9), (50, 16, 15), (8, 3, 7), (300, 7, 40)])
def test_identity_solver_reproduces_input_exactly(kinect, W, H, L):
    cfg = EngineConfig(rate_hz=kinect.rate_hz, window=W, hop=H, lookahead=L)
    out, _ = run(StreamEngine(KINECT_V2, cfg, identity_solver), frames_of(kinect, uniform=True))
    live, clean = split(out)
    assert len(clean) == kinect.n_frames and not any(f.filled for f in clean)
    got = body_array(clean)
    assert np.array_equal(got, kinect.positions)  # bit for bit: weights sum to 1
    assert not any(f.bodies[0].recovered.any() for f in clean)


def test_overlap_add_weights_sum_to_one(kinect):
    cfg = EngineConfig(rate_hz=kinect.rate_hz, window=40, hop=3, lookahead=20)
    out, _ = run(StreamEngine(KINECT_V2, cfg, offset_solver), frames_of(kinect, uniform=True))
    got = body_array(split(out)[1])
    np.testing.assert_allclose(got, kinect.positions + 0.125, rtol=0, atol=1e-12)


def test_clean_leaves_after_fixed_lookahead(kinect):
    L = 15
    cfg = EngineConfig(rate_hz=kinect.rate_hz, window=60, hop=5, lookahead=L)
    engine = StreamEngine(KINECT_V2, cfg, savgol_solver)
    frames = list(frames_of(kinect, uniform=True))
    for i, f in enumerate(frames):
        got = engine.push(f)
        live = [o for k, o in got if k == "live"]
        clean = [o for k, o in got if k == "clean"]
        assert [o.seq for o in live] == [f.seq]  # live: at once, every frame
        if i < L:
            assert clean == []
        else:  # steady state: exactly the frame L behind, one per push
            assert [o.seq for o in clean] == [frames[i - L].seq]
    rest = [o for k, o in engine.flush() if k == "clean"]
    assert [o.seq for o in rest] == [f.seq for f in frames[-L:]]
    assert engine.metrics()["lookahead_s"] == pytest.approx(L / kinect.rate_hz)


# ----------------------------------------------------------------------------- drops, NaN, bodies
def test_frame_drops_are_filled_and_flagged(kinect):
    frames = list(frames_of(kinect, uniform=True))
    dropped = {40, 41, 42, 90}
    kept = [f for i, f in enumerate(frames) if i not in dropped]
    out, _ = run(StreamEngine(KINECT_V2, EngineConfig(rate_hz=kinect.rate_hz), savgol_solver), kept)
    live, clean = split(out)
    assert len(live) == len(clean) == len(frames)
    for stream in (live, clean):
        filled = [i for i, f in enumerate(stream) if f.filled]
        assert filled == sorted(dropped)
        assert [f.seq for f in stream] == list(range(100, 100 + len(frames)))
        for i in filled:
            b = stream[i].bodies[0]
            assert b.body_id == 7
            assert b.recovered.all() and np.isfinite(b.positions).all()
            assert (b.confidence == 0.5).all()  # SPEC: the service's estimate, not the sensor's
            assert stream[i].sensor_time_ns == frames[i].sensor_time_ns  # evenly re-timed
    # filled clean values lie between their neighbours' (solver bridged the gap)
    gap = body_array(clean[39:44])
    assert np.abs(gap[1:4] - gap[0]).max() < 0.3


def test_nan_joints_are_missing(kinect):
    frames = list(frames_of(kinect, uniform=True))
    for f in frames[30:45]:
        f.bodies[0].positions[[6, 7]] = np.nan  # left wrist/hand lost, confidence still 1
        f.bodies[0].positions[3, 1] = np.inf
    out, _ = run(StreamEngine(KINECT_V2, EngineConfig(rate_hz=kinect.rate_hz), savgol_solver), frames)
    live, clean = split(out)
    for stream in (live, clean):
        for f in stream[30:45]:
            b = f.bodies[0]
            assert np.isfinite(b.positions).all()
            assert b.recovered[[3, 6, 7]].all()
    truth = kinect.positions[30:45][:, [6, 7]]
    err = np.linalg.norm(body_array(clean[30:45])[:, [6, 7]] - truth, axis=2)
    assert err.max() < 0.25  # bridged, not thrown to the origin


def test_wrong_joint_count_rejected_with_expected_count(kinect):
    engine = StreamEngine(KINECT_V2, EngineConfig(rate_hz=30.0), savgol_solver)
    frames = list(frames_of(kinect, uniform=True))[:40]
    engine.push(frames[0])
    bad = SkeletonFrame("k", 101, frames[1].sensor_time_ns, KINECT_V2.name, [BodyFrame(7, np.zeros((24, 3)), np.ones(24))])
    with pytest.raises(ValueError, match=r"expected 25 joints"):
        engine.push(bad)
    unknown = SkeletonFrame("k", 101, frames[1].sensor_time_ns, "nope", [])
    with pytest.raises(ValueError, match="kinect_v2"):
        engine.push(unknown)
    out = [o for f in frames[1:] for o in engine.push(f)] + engine.flush()
    live, clean = split(out)
    assert len(live) == 39 and len(clean) == 40
    assert engine.metrics()["frames_rejected"] == 2


def test_late_and_duplicate_frames_are_counted_and_skipped(kinect):
    engine = StreamEngine(KINECT_V2, EngineConfig(rate_hz=30.0), savgol_solver)
    frames = list(frames_of(kinect, uniform=True))[:30]
    out = []
    for i, f in enumerate(frames):
        out += engine.push(f)
        if i == 10:
            out += engine.push(frames[5])  # reordered
            out += engine.push(f)  # duplicate
    out += engine.flush()
    assert engine.metrics()["frames_dropped_late"] == 2
    assert [f.seq for f in split(out)[1]] == [f.seq for f in frames]


def _two_body_frames(motion, presence2):
    """Body 1 always; body 2 (the same motion shifted 1 m) where presence2[i]."""
    for i in range(motion.n_frames):
        bodies = [BodyFrame(1, motion.positions[i].copy(), motion.confidence[i].copy())]
        if presence2[i]:
            bodies.append(BodyFrame(2, motion.positions[i] + [1.0, 0, 0], motion.confidence[i].copy()))
        yield SkeletonFrame("k", i, int(round(i / 30.0 * NS)), KINECT_V2.name, bodies)


def test_bodies_appear_disappear_and_reidentify(kinect):
    T = kinect.n_frames
    present = np.zeros(T, bool)
    present[20:60] = True  # appears at 20
    present[68:100] = True  # gone 8 frames (< 1 s grace): the same body
    present[140:] = True  # gone 40 frames (> 1 s): timed out, then re-identified
    frames = list(_two_body_frames(kinect, present))
    engine = StreamEngine(KINECT_V2, EngineConfig(rate_hz=30.0, body_timeout_s=1.0), savgol_solver)
    out, _ = run(engine, frames)
    live, clean = split(out)
    assert len(live) == len(clean) == T
    for stream in (live, clean):
        for i, f in enumerate(stream):
            assert [b.body_id for b in f.bodies] == [b.body_id for b in frames[i].bodies]
            for b in f.bodies:
                assert np.isfinite(b.positions).all()
    m = engine.metrics()
    assert m["bodies_seen"] == 3  # body 1, body 2, body 2 again after its timeout
    assert m["bodies_timed_out"] == 1
    assert m["bodies_reidentified"] == 1
    # body 2's clean output stays on body 2 (1 m to the side), not mixed with body 1
    b2 = np.array([next(b for b in f.bodies if b.body_id == 2).positions[0] for f in clean if len(f.bodies) == 2])
    b1 = np.array([f.bodies[0].positions[0] for f in clean if len(f.bodies) == 2])
    np.testing.assert_allclose(b2[:, 0] - b1[:, 0], 1.0, atol=0.05)


def test_multiple_streams_are_independent(kinect):
    engine = StreamEngine(KINECT_V2, EngineConfig(rate_hz=30.0), savgol_solver)
    a = list(frames_of(kinect, uniform=True, stream="a", seq0=0))
    b = list(frames_of(kinect, uniform=True, stream="b", seq0=5000))
    out = []
    for fa, fb in zip(a, b):
        out += engine.push(fa) + engine.push(fb)
    out += engine.flush()
    for sid, seq0 in (("a", 0), ("b", 5000)):
        clean = [f for k, f in out if k == "clean" and f.stream_id == sid]
        assert [f.seq for f in clean] == list(range(seq0, seq0 + kinect.n_frames))


# ----------------------------------------------------------------------------- threads and degradation
class GatedSolver:
    """A savgol solver that blocks until ``release`` is set (a stalled solver, no timing)."""

    def __init__(self):
        self.release = threading.Event()
        self.started = threading.Event()
        self.calls = 0
        self.iterations_seen = []

    def __call__(self, positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
        self.calls += 1
        self.started.set()
        self.release.wait(timeout=60)
        return savgol_solver(positions, confidence, bones, bone_lengths, rate_hz)


def test_threaded_push_never_blocks_on_a_stalled_solver_and_degrades(kinect):
    solver = GatedSolver()
    cfg = EngineConfig(rate_hz=30.0, max_clean_delay_s=1.0)
    engine = ThreadedStreamEngine(KINECT_V2, cfg, solver)
    frames = list(frames_of(kinect, uniform=True))
    out: list = []

    def feed():
        for i, f in enumerate(frames):
            out.extend(engine.push(f))
            if i == 90:
                # the pool's thread runs niced below this one: on a busy machine it could reach the
                # first window only after the last push, and nothing would have stalled; the
                # stall starts here, and the rest of the frames are pushed against it
                solver.started.wait(timeout=10)

    t = threading.Thread(target=feed, daemon=True)
    t.start()
    t.join(timeout=60)
    try:
        assert not t.is_alive(), "push blocked on the stalled window solver"
        assert solver.started.is_set()
        live, clean = split(out)
        assert [f.seq for f in live] == [f.seq for f in frames]  # live never waits for the solver
        m = engine.metrics()
        assert m["degraded"] and m["degrade_level"] >= 1
        assert m["windows_skipped"] + m["windows_abandoned"] > 0
        assert m["hop"] > cfg.hop or m["max_iterations"] is not None
        # the stalled window was abandoned after max_clean_delay: clean still flows (live fallback)
        assert len(clean) > 0
        assert [f.seq for f in clean] == [f.seq for f in frames[: len(clean)]]
    finally:
        solver.release.set()
    rest = engine.flush(timeout=30)
    engine.close()
    clean = split(out + rest)[1]
    assert [f.seq for f in clean] == [f.seq for f in frames]  # every frame once, in order
    for f in clean:
        assert np.isfinite(f.bodies[0].positions).all()


def test_threaded_equals_synchronous_when_keeping_up(kinect):
    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    sync = split(run(StreamEngine(KINECT_V2, cfg, savgol_solver), frames_of(kinect, uniform=True))[0])[1]
    # numbered from 0 like the synchronous engine's body (the shared pool numbers all threaded engines' bodies)
    threaded = run_threaded(ThreadedStreamEngine(KINECT_V2, cfg, savgol_solver, body_ordinals=itertools.count().__next__),
                            frames_of(kinect, uniform=True))
    assert [f.seq for f in threaded] == [f.seq for f in sync]
    assert np.array_equal(body_array(threaded), body_array(sync))


def test_clean_on_poll_leaves_the_clean_work_to_poll_with_the_same_output(kinect):
    """``clean_on_poll`` (serve): push returns the live frame only, poll the clean frames,
    which are those of the synchronous engine; a push that finds the last frame not drained
    (no poll between) drains it first, so nothing waits on a caller that never polls."""
    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    sync = split(run(StreamEngine(KINECT_V2, cfg, savgol_solver), frames_of(kinect, uniform=True))[0])[1]
    engine = ThreadedStreamEngine(KINECT_V2, cfg, savgol_solver, body_ordinals=itertools.count().__next__,
                                  clean_on_poll=True)
    out = []
    for f in frames_of(kinect, uniform=True):
        got = engine.push(f)
        assert [k for k, _ in got] == ["live"]
        out += got + engine.poll()
    out += engine.flush()
    engine.close()
    clean = split(out)[1]
    assert [f.seq for f in clean] == [f.seq for f in sync]
    assert np.array_equal(body_array(clean), body_array(sync))

    engine = ThreadedStreamEngine(KINECT_V2, cfg, savgol_solver, body_ordinals=itertools.count().__next__,
                                  clean_on_poll=True)
    pushed = []
    for f in frames_of(kinect, uniform=True):  # never polled
        pushed.append(engine.push(f))
        # a sensor's frame period (three of them here) between pushes, as serve has: the pool
        # solves the windows the push handed it in the meantime, so the next push has a frame
        # to drain whatever the test machine's load. Back to back, every push could come
        # before the first window was solved (a window scheduled by a push is handed to the
        # pool by the next one, so a few frames here always wait the whole period).
        deadline = time.monotonic() + 3.0 / 30.0
        while engine.metrics()["pending_windows"] and time.monotonic() < deadline:
            time.sleep(0.001)
    assert all([k for k, _ in got][-1] == "live" for got in pushed)
    assert any(k == "clean" for got in pushed for k, _ in got)  # drained by the next push
    clean = split([o for got in pushed for o in got] + engine.flush())[1]
    engine.close()
    assert [f.seq for f in clean] == [f.seq for f in sync]
    assert np.array_equal(body_array(clean), body_array(sync))


def test_config_rejects_inconsistent_window_hop_lookahead():
    with pytest.raises(ValueError, match="hop"):
        EngineConfig(window=60, hop=20, lookahead=15)
    with pytest.raises(ValueError, match="lookahead"):
        EngineConfig(window=60, hop=5, lookahead=60)
    cfg = EngineConfig(rate_hz=30.0, lookahead_s=0.5)
    assert cfg.lookahead == 15 and cfg.hop <= 16
    for bad in (0, 11):  # the start-up hop is 1..hop frames
        with pytest.raises(ValueError, match="startup_hop must be in 1..hop = 1..10 frames"):
            EngineConfig(rate_hz=30.0, startup_hop=bad)
    assert EngineConfig(rate_hz=30.0, hop=1).startup_hop == 1


def test_stalled_solver_and_a_departed_body_do_not_hold_the_stream(kinect):
    """A body that left while its last window is stuck must not block clean output."""
    solver = GatedSolver()
    T = kinect.n_frames
    present = np.zeros(T, bool)
    present[:30] = True  # body 2 leaves at frame 30 and times out 1 s later
    frames = list(_two_body_frames(kinect, present))
    engine = ThreadedStreamEngine(KINECT_V2, EngineConfig(rate_hz=30.0, max_clean_delay_s=1.0), solver)
    out = []
    try:
        for f in frames:
            out += engine.push(f)
        clean = split(out)[1]
        # bounded backlog: lookahead + 1 s of frames at most are still waiting
        assert len(clean) >= T - (15 + 1 + 30) - 2
        assert [f.seq for f in clean] == [f.seq for f in frames[: len(clean)]]
    finally:
        solver.release.set()
    out += engine.flush(timeout=30)
    engine.close()
    assert [f.seq for f in split(out)[1]] == [f.seq for f in frames]


def test_degraded_windows_get_fewer_solver_iterations(kinect):
    """Level 1 of degradation halves the iteration cap handed to the window solver."""
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Cfg:
        max_iterations: int = 100

    seen = []
    release = threading.Event()

    def solver(positions, confidence, bones, bone_lengths, rate_hz, config=Cfg(), state=None, init=None):
        seen.append(config.max_iterations)
        release.wait(timeout=60)
        return savgol_solver(positions, confidence, bones, bone_lengths, rate_hz)

    cfg = EngineConfig(rate_hz=30.0, max_iterations=40, max_pending_windows=100, max_clean_delay_s=100.0)
    engine = ThreadedStreamEngine(KINECT_V2, cfg, solver)
    frames = list(frames_of(kinect, uniform=True))
    try:
        for f in frames[:60]:
            engine.push(f)
        m = engine.metrics()
        assert m["degraded"] and m["max_iterations"] < 40
    finally:
        release.set()
    engine.flush(timeout=30)
    engine.close()
    assert seen[0] == 40  # the first window, before the solver fell behind
    assert min(seen) <= 20  # later ones with the degraded cap



def test_a_bodys_first_window_fills_with_extra_windows_then_the_regular_grid(kinect):
    """serve's schedule at 30 Hz (W 60, H 10, L 15, start-up hop 5): windows end every 5
    frames from 16 while the first window fills (end < 60), then on the regular grid 66,
    76, ..., the same as without start-up windows; a body whose grid a phase shifts keeps
    its shifted grid."""
    from streamfix.streaming.blending import next_window_end, window_ends

    cfg = EngineConfig(rate_hz=30.0)
    assert (cfg.window, cfg.hop, cfg.lookahead, cfg.startup_hop) == (60, 10, 15, 5)
    lengths: list[int] = []

    def solver(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
        lengths.append(len(positions))
        return identity_solver(positions, confidence, bones, bone_lengths, rate_hz)

    engine = StreamEngine(KINECT_V2, cfg, solver)
    T = 140
    for i in range(T):
        engine.push(SkeletonFrame("k", i, int(i * NS / 30), KINECT_V2.name,
                                  [BodyFrame(0, kinect.positions[i].copy(), kinect.confidence[i].copy())]))
    ends = window_ends(T, 15, 10, 60, 5)
    assert list(ends[:13]) == [16, 21, 26, 31, 36, 41, 46, 51, 56, 61, 66, 76, 86]
    assert lengths[:11] == [16, 21, 26, 31, 36, 41, 46, 51, 56, 60, 60]
    assert len(lengths) == engine.metrics()["windows_scheduled"] == int((ends <= T).sum())
    # phase 6 (grid 10 + 10 k): 16, then the start-up windows stop at grid points too
    got, end = [], 16
    while end < 90:
        end = next_window_end(end, 60, 10, 5, 10)
        got.append(end)
    assert got == [20, 25, 30, 35, 40, 45, 50, 55, 60, 70, 80, 90]
    assert EngineConfig.for_files(30.0).startup_hop == EngineConfig.for_files(30.0).hop  # files: none


def test_start_up_windows_are_owed_not_an_overload(kinect):
    """While their first windows fill, bodies owe hop / startup_hop windows per hop: the
    overload test counts that many in flight as normal (12 bodies starting together were
    degraded by the extra windows in bench_service), and one per body afterwards."""
    cfg = EngineConfig(rate_hz=30.0)
    engine = StreamEngine(KINECT_V2, cfg, identity_solver)

    def push(i):
        bodies = [BodyFrame(b, kinect.positions[i].copy(), kinect.confidence[i].copy()) for b in range(3)]
        engine.push(SkeletonFrame("k", i, int(i * NS / 30), KINECT_V2.name, bodies))

    for i in range(30):
        push(i)
    assert engine._windows_due() == 3 * cfg.hop / cfg.startup_hop == 6
    for i in range(30, 70):
        push(i)
    assert engine._windows_due() == 3


class _QueuedPool:
    """The shared solver pool, reporting ``queued`` windows waiting whatever it holds."""

    def __init__(self, pool, queued):
        self._pool, self.queued = pool, queued

    def submit(self, task):
        self._pool.submit(task)


def _wait_for_worker(engine, timeout_s: float = 10.0) -> None:
    """Block until every window ``engine`` submitted has been solved (bounded)."""
    with engine._cond:
        assert engine._cond.wait_for(lambda: engine._inflight == 0, timeout_s), "the solver pool stalled"


@pytest.mark.parametrize("queued, degrade, extras", [(0, True, True), (3, True, False), (3, False, True)])
def test_start_up_windows_wait_for_an_idle_solver(kinect, queued, degrade, extras):
    """A starting body's extra windows (every startup_hop frames) are solved only while no
    window waits in the shared pool: many bodies starting together multiplied the solver's
    work and serve's clean output fell behind for seconds. Under the overload policy only
    (degrade=False keeps the configured schedule, as synchronous engines do)."""
    cfg = EngineConfig(rate_hz=30.0, degrade=degrade)
    engine = ThreadedStreamEngine(KINECT_V2, cfg, identity_solver, body_ordinals=itertools.count().__next__)
    engine._pool = _QueuedPool(engine._pool, queued)
    for f in itertools.islice(frames_of(kinect, uniform=True), 90):
        engine.push(f)
        engine.poll()  # submits the frame's window, if any
        _wait_for_worker(engine)  # frames faster than the worker would raise the overload level
    assert engine.level == 0  # only the pool's queue decides here
    scheduled = engine.metrics()["windows_scheduled"]
    engine.flush()
    engine.close()
    from streamfix.streaming.blending import window_ends

    grid = window_ends(90, cfg.lookahead, cfg.hop)
    with_extras = window_ends(90, cfg.lookahead, cfg.hop, cfg.window, cfg.startup_hop)
    expect = with_extras if extras else grid
    assert scheduled == int((expect <= 90).sum())
    assert int((with_extras <= 90).sum()) > int((grid <= 90).sum())  # there are extras to skip


# ----------------------------------------------------------------------------- output smoothing
def noisy_identity(share):
    """The identity solver that reports its window as ``share`` sensor noise."""
    from streamfix.streaming.solver_api import NOISE_SHARE_KEY

    def solve(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
        return WindowOutput(positions.copy(), ~(confidence > 0), None, 1, True, {NOISE_SHARE_KEY: share})

    return solve


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_output_smoothing_is_the_twiced_binomial_of_noisy_windows(kinect, share):
    """Windows that report sensor noise get the kernel on their blended output: with the
    identity solver, every frame with 2h blended neighbours each side is the kernel over
    the input (the future neighbours are the newest window's values: no extra latency),
    a body's first and last 2h frames keep theirs (h = 2 frames at 30 Hz)."""
    from streamfix.core.filters import twiced_binomial_taps

    cfg = EngineConfig(rate_hz=kinect.rate_hz)
    h = cfg.output_smooth_frames
    assert h == 2
    out, _ = run(StreamEngine(KINECT_V2, cfg, noisy_identity(share)), frames_of(kinect, uniform=True))
    got = body_array(split(out)[1])
    x = kinect.positions
    assert np.isfinite(x).all()
    taps = twiced_binomial_taps(h)
    T, r = len(x), 2 * h
    smooth = sum(t * x[k:T - 2 * r + k] for k, t in enumerate(taps))
    expect = x.copy()
    expect[r:T - r] = share * smooth + (1.0 - share) * x[r:T - r]
    np.testing.assert_allclose(got, expect, rtol=0, atol=1e-12)
    assert np.abs(got - x).max() > 1e-4  # it smoothed


def test_output_smoothing_threaded_equals_synchronous(kinect):
    from streamfix.streaming.solver_api import NOISE_SHARE_KEY

    def noisy_savgol(*args, **kwargs):
        res = savgol_solver(*args, **kwargs)
        res.info = {NOISE_SHARE_KEY: 1.0}
        return res

    cfg = EngineConfig(rate_hz=30.0, degrade=False, max_pending_windows=10**6, max_clean_delay_s=1e6)
    sync = split(run(StreamEngine(KINECT_V2, cfg, noisy_savgol), frames_of(kinect, uniform=True))[0])[1]
    plain = split(run(StreamEngine(KINECT_V2, cfg, savgol_solver), frames_of(kinect, uniform=True))[0])[1]
    assert np.abs(body_array(sync) - body_array(plain)).max() > 1e-5
    threaded = run_threaded(ThreadedStreamEngine(KINECT_V2, cfg, noisy_savgol, body_ordinals=itertools.count().__next__),
                            frames_of(kinect, uniform=True))
    assert np.array_equal(body_array(threaded), body_array(sync))


def test_twiced_binomial_keeps_quadratic_motion_and_removes_frame_jitter():
    from streamfix.core.filters import binomial_taps, twiced_binomial_taps

    for h in (1, 2, 4):
        taps = twiced_binomial_taps(h)
        k = np.arange(len(taps)) - len(taps) // 2
        assert len(taps) == 4 * h + 1 and np.allclose(taps, taps[::-1])
        assert abs(taps.sum() - 1.0) < 1e-12 and abs((taps * k).sum()) < 1e-12
        assert abs((taps * k ** 2).sum()) < 1e-12  # a quadratic passes unchanged
        assert abs((taps * (-1.0) ** k).sum()) < 1e-12  # alternating jitter is removed
        assert abs((binomial_taps(h) * (np.arange(2 * h + 1) - h) ** 2).sum() - h / 2) < 1e-12


# ----------------------------------------------------------------------------- released samples
def releasing_solver(x_all, joint, start, seen, report=True):
    """The identity solver, except that a window which has seen at least ``seen`` frames from
    ``start`` on releases ``joint`` there (the sensor's frozen guess, as the default solver's
    frozen-limb release judges it) and answers about 1 m to the side (1 m + 1 mm per frame of
    its end, so windows differ); with ``report``, it says so in ``info`` as the default solver
    does. ``x_all``: the whole input, to find where a window ends."""
    from streamfix.streaming.solver_api import RELEASED_KEY

    def solve(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
        last = positions[-1, 0]
        end = int(np.flatnonzero((x_all[:, 0] == last).all(axis=1))[0]) + 1
        out = positions.copy()
        released = np.zeros(confidence.shape, bool)
        if end - start >= seen:
            first = max(0, start - (end - len(positions)))
            released[first:, joint] = True
            out[first:, joint, 0] += 1.0 + 0.001 * end
        info = {RELEASED_KEY: released} if report else {}
        return WindowOutput(out, released | ~(confidence > 0), None, 1, True, info)

    return solve


@pytest.mark.parametrize("schedule", ["serve", "file"])
def test_a_released_sample_drops_what_windows_that_kept_it_blended(kinect, schedule):
    """An older window that saw too little of a frozen run kept the sensor's pose there; what
    it blended into a sample a newer window released is dropped: every frame is either
    wholly the releasing windows' values or (no releasing window reached it) wholly the
    input's. The releasing windows crossfade with each other as usual. Without the report,
    the hand-over frames come out between the input and the release."""
    x = kinect.positions
    assert len(np.unique(x[:, 0, 0])) == len(x)  # a window's last frame tells where it ends
    # the file schedule's shape (the lookahead most of the window, no start-up windows) at 3 s
    # windows: the take is one file window
    files = EngineConfig.for_files(30.0, window=90, hop=40, lookahead=60)
    cfg = EngineConfig(rate_hz=30.0) if schedule == "serve" else files
    start, joint = 60, 5
    got = {}
    for report in (True, False):
        solver = releasing_solver(x, joint, start, cfg.lookahead, report)
        clean = split(run(StreamEngine(KINECT_V2, cfg, solver), frames_of(kinect, uniform=True))[0])[1]
        got[report] = body_array(clean)
    shift = got[True][:, joint, 0] - x[:, joint, 0]
    assert np.allclose(shift[:start], 0.0, atol=1e-12)
    released = shift > 1.0 - 1e-9  # only releasing windows' values (each 1 m + 1 mm per frame of its end)
    assert (released | np.isclose(shift, 0.0, rtol=0, atol=1e-12)).all()
    assert released[start + cfg.lookahead:].all()
    one_window = np.isclose(shift[released][:, None], 1.0 + 0.001 * np.arange(len(x) + 1)[None, :],
                            rtol=0, atol=1e-9).any(axis=1)
    assert not one_window.all()  # some frames are crossfades of two releasing windows
    other = np.setdiff1d(np.arange(x.shape[1]), [joint])
    assert np.array_equal(got[True][:, other], got[False][:, other])  # the other joints blend as before
    blended = got[False][:, joint, 0] - x[:, joint, 0]
    assert ((blended > 1e-3) & (blended < 1 - 1e-3)).any()  # the test can fail: blends exist without it
