"""The service's hardening parts in isolation: numbering, skeleton scope, backlog policy, limits."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.service.limits import LIMITS, Limits
from streamfix.service.numbering import SEQ_LIMIT, Numbering
from streamfix.service.scope import SkeletonScope
from streamfix.service.backlog import MAX_KEPT_STREAMS, Backlog
from streamfix.service.validate import LimitHit, check_rate, limit_coordinates
from streamfix.skeletons import KINECT_V2, Skeleton


def test_numbering_keeps_seq_within_uint64_and_epochs_increasing():
    num = Numbering()
    num.restart()
    e0 = num.epoch
    assert [num.wire(s) for s in (SEQ_LIMIT - 2, SEQ_LIMIT - 1, SEQ_LIMIT, SEQ_LIMIT + 1)] == [
        (e0, SEQ_LIMIT - 2), (e0, SEQ_LIMIT - 1), (e0 + 1, 0), (e0 + 1, 1)]
    assert num.wire(SEQ_LIMIT - 1) == (e0, SEQ_LIMIT - 1), "a clean frame of an earlier instant keeps its numbering"
    num.restart()  # a new engine numbers from its own first input seq (here 0): the wire continues
    e1 = num.epoch
    assert e1 > e0 + 1 and num.wire(0) == (e1, 2) and num.wire(1) == (e1, 3)
    assert num.restarts == 1
    fresh = Numbering()
    fresh.restart()
    assert fresh.wire(41) == (fresh.epoch, 41), "the first epoch keeps the producer's numbering"


def test_skeleton_scope_isolates_streams_and_protects_builtins():
    scope = SkeletonScope(Limits(max_announcements=3))
    arm = Skeleton("arm3", ("a", "b", "c"), ((0, 1), (1, 2)))
    scope.announce("s1", arm, 30.0)
    assert scope.table("s1")["arm3"] == arm and "arm3" not in scope.table("s2")
    assert scope.rate("s1", "arm3") == 30.0
    with pytest.raises(LimitHit) as hit:
        scope.announce("s2", Skeleton("kinect_v2", ("a", "b"), ((0, 1),)), 30.0)
    assert hit.value.limit == "builtin_skeleton"
    scope.announce("s2", KINECT_V2, 30.0)  # the built-in layout itself is fine
    for bad, limit in ((Skeleton("x" * 65, ("a", "b"), ((0, 1),)), "name"),
                       (Skeleton("big", tuple(f"j{i}" for i in range(1025)), ()), "joints")):
        with pytest.raises(LimitHit) as hit:
            scope.announce("s3", bad, 30.0)
        assert hit.value.limit == limit
    with pytest.raises(LimitHit, match="outside"):
        scope.announce("s3", arm, 1e8)
    scope.activate("s1")
    for k in range(10):  # streams that never send a frame: bounded, oldest forgotten, active kept
        scope.announce(f"idle{k}", arm, 30.0)
    assert len(scope) == 4 and "arm3" in scope.table("s1") and scope.forgotten == 8
    scope.forget("s1")
    assert scope.table("s1") == {}


def test_backlog_sheds_the_oldest_by_age_and_count_and_block_never_sheds():
    """Count bound: the oldest go. Age bound: all but each stream's newest frame go, so a
    burst that ends while the loop is busy still reaches live (with its shed count)."""
    b = Backlog(max_frames=5, max_age_s=0.05)
    now = time.monotonic_ns()
    for k in range(8):
        b.put([b"sf/raw/a", bytes([k])], now)
    b.put([b"sf/meta/a", b"m"], now)
    got, shed = b.take(0, 100)
    assert shed == {"a": 3} and [p[0][1] for p in got] == [b"m", b"\x03", b"\x04", b"\x05", b"\x06", b"\x07"]
    stale = time.monotonic_ns() - 10**9  # waited a second already
    for k in range(3):
        b.put([b"sf/raw/b", bytes([k])], stale)
    b.put([b"sf/raw/c", b"c"], stale)
    b.put([b"sf/raw/d", b"d"], time.monotonic_ns())
    got, shed = b.take(0, 100)
    # the stale frames go, except each stream's newest: live jumps to the latest pose sent
    assert shed == {"b": 2} and [p[0][1] for p in got] == [b"\x02", b"c", b"d"]
    assert b.depth()[0] == 0 and not b._waiting
    # a flood of stream names: the newest frame is kept for at most MAX_KEPT_STREAMS of them
    flood = Backlog(max_frames=5000, max_age_s=0.05)
    for k in range(MAX_KEPT_STREAMS + 100):
        flood.put([f"sf/raw/s{k}".encode(), b"x"], stale)
    got, shed = flood.take(0, 10_000)
    assert len(got) == MAX_KEPT_STREAMS and sum(shed.values()) == 100
    assert [p[0] for p, *_ in got][0] == b"sf/raw/s100"  # the oldest were shed
    blocking = Backlog(max_frames=1000, max_age_s=0.05, policy="block")
    old = time.monotonic_ns() - 10**10
    for k in range(50):
        blocking.put([b"sf/raw/a", b"x"], old)
    got, shed = blocking.take(0, 100)
    assert len(got) == 50 and shed == {}
    with pytest.raises(ValueError, match="overload policy"):
        Backlog(policy="drop-newest")


def test_backlog_wake_ends_a_wait_for_input_without_losing_input():
    """The service loop waits in take() for input; a solver thread that finished a window
    wakes it so the clean frames go out now. A wake before the wait makes the next take
    return at once, and only that one."""
    b = Backlog()
    threading.Timer(0.05, b.wake).start()
    t0 = time.monotonic()
    got, shed = b.take(30.0, 10)
    assert (got, shed) == ([], {}) and time.monotonic() - t0 < 15.0
    b.wake()
    t0 = time.monotonic()
    assert b.take(30.0, 10) == ([], {}) and time.monotonic() - t0 < 15.0
    t0 = time.monotonic()
    b.take(0.2, 10)  # the wake was used up: this one waits its timeout
    assert time.monotonic() - t0 >= 0.15
    b.put([b"sf/raw/a", b"x"], time.monotonic_ns())
    b.wake()
    got, _ = b.take(30.0, 10)
    assert [p[1] for p, *_ in got] == [b"x"]


def test_far_coordinates_become_missing_and_rates_are_bounded():
    pos = np.zeros((25, 3))
    pos[3] = [3e38, 0, 0]
    pos[4] = [0, -51.0, 0]
    pos[5] = np.nan
    frame = SkeletonFrame("s", 0, 0, "kinect_v2", [BodyFrame(0, pos, np.ones(25))])
    assert limit_coordinates(frame, 50.0) == 2
    body = frame.bodies[0]
    assert np.isnan(body.positions[[3, 4]]).all() and (body.confidence[[3, 4]] == 0).all()
    assert body.confidence[0] == 1.0 and pos[3, 0] == 3e38, "the input array is not modified"
    limits = Limits()
    assert check_rate("s", 30.0, limits) == 30.0
    for bad in (0.5, 241.0, float("nan"), float("inf")):
        with pytest.raises(LimitHit):
            check_rate("s", bad, limits)
    assert set(LIMITS) >= {"message_size", "streams", "bodies_stream", "rate", "coordinate", "builtin_skeleton"}
    with pytest.raises(ValueError, match="must be > 0"):
        Limits(max_streams=0)


def test_the_service_decodes_and_validates_with_one_scope_even_while_it_is_empty():
    from streamfix.service.server import Service
    from streamfix.service.sources import ZmqSource

    source = ZmqSource("tcp://127.0.0.1:0")
    try:
        assert len(source.scope) == 0
        svc = Service(source, publisher=None, make_engine=None, status_interval_s=0)
        assert svc.scope is source.scope, "a layout the source learns must be the one the service validates with"
    finally:
        source.close()


def test_bodies_are_admitted_within_the_joint_rate_budget():
    from test_service_loop import RecordingPublisher, ScriptedSource

    from streamfix.service.engines import EngineOptions, engine_factory
    from streamfix.service.server import Service
    from streamfix.service.items import Announce, Frame

    big = Skeleton("grid400", tuple(f"j{i}" for i in range(400)), ())
    items = [Announce("g", big, 200.0)]  # 400 joints x 200 Hz = 80,000 joint-samples/s per body
    for k in range(3):
        bodies = [BodyFrame(b, np.zeros((400, 3)), np.ones(400)) for b in range(4)]
        items.append(Frame(SkeletonFrame("g", k, k * 5_000_000, "grid400", bodies), 0))
    pub = RecordingPublisher()
    svc = Service(ScriptedSource(items), pub, engine_factory("passthrough", EngineOptions()), status_interval_s=0,
                  limits=Limits(max_joint_rate=200_000.0))
    svc.run()
    live = [f for kind, f in pub.sent if kind == "live"]
    assert [len(f.bodies) for f in live] == [2, 2, 2], "two bodies fit 200,000 joints x Hz, the others are refused"
    assert svc.m.limit_hits.value(limit="bodies_stream") == 6
