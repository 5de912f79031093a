"""Real loopback sockets: the zmq_io Subscriber/FramePublisher and the Python reference subscriber.

``LoopbackPublisher`` is shared with the tap/record/C++ tests: a PUB bound to a random
127.0.0.1 port that publishes real encoded frames from a thread (bounded count) until
stopped, so subscribers that join late still receive frames.
"""
from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.skeletons import KINECT_V2, Skeleton
from streamfix.transport import wire
from streamfix.transport.zmq_io import FramePublisher, Subscriber

PROJECT = Path(__file__).resolve().parents[1]
REFERENCE = PROJECT / "protocol" / "python" / "subscriber.py"


def expected_positions(seq: int, body_id: int, n_joints: int) -> np.ndarray:
    """The deterministic pose a LoopbackPublisher sends: any subscriber can recompute it."""
    j = np.arange(n_joints, dtype=np.float64)
    pos = np.stack([0.01 * j + 0.001 * seq, 1.0 + 0.02 * j, 2.0 + 0.1 * body_id + 0.0001 * seq + 0 * j], axis=1)
    return pos.astype(np.float32).astype(np.float64)


MISSING_JOINT = 3  # always NaN in published frames
RECOVERED_JOINT = 7  # always flagged recovered on live/clean


class LoopbackPublisher:
    """Publish frames on ``sf/<kind>/<stream>`` from a thread: 2 bodies, joint 3 missing.

    ``garbage_every``: after every n-th frame also send a garbage payload on the same
    topic. ``skeleton``: a custom layout is announced by skeleton messages (every
    ``meta_interval_s``).
    """

    def __init__(self, kind: str = "live", stream: str = "kinect0", skeleton: Skeleton = KINECT_V2,
                 rate_hz: float = 200.0, garbage_every: int = 0, max_frames: int = 20000,
                 meta_interval_s: float = 0.2) -> None:
        self.kind, self.stream, self.skeleton = kind, stream, skeleton
        self.period = 1.0 / rate_hz
        self.garbage_every, self.max_frames = garbage_every, max_frames
        self.pub = FramePublisher("tcp://127.0.0.1:*", meta_interval_s=meta_interval_s)
        self.endpoint = self.pub.endpoint
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def frame(self, seq: int) -> SkeletonFrame:
        J = self.skeleton.n_joints
        bodies = []
        for body_id in (1, 4):
            pos = expected_positions(seq, body_id, J)
            pos[MISSING_JOINT] = np.nan
            conf = np.ones(J)
            conf[MISSING_JOINT] = 0.0
            rec = None
            if self.kind != "raw":
                rec = np.zeros(J, bool)
                rec[RECOVERED_JOINT] = True
            bodies.append(BodyFrame(body_id, pos, conf, rec))
        return SkeletonFrame(self.stream, seq, seq * 33_333_333, self.skeleton.name, bodies)

    def _run(self) -> None:
        self.pub.announce(self.stream, self.skeleton, 30.0)
        topic = wire.topic_for(self.kind, self.stream)
        while not self._stop.is_set() and self.sent < self.max_frames:
            self.pub.publish(self.kind, self.frame(self.sent))
            self.sent += 1
            if self.garbage_every and self.sent % self.garbage_every == 0:
                self.pub.send_raw(topic, b"\xc1 not msgpack")
            time.sleep(self.period)

    def __enter__(self) -> "LoopbackPublisher":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5)
        self.pub.close()


def test_subscriber_counts_and_skips_bad_messages_and_keeps_the_rest():
    ctx = zmq.Context()
    pub = FramePublisher("tcp://127.0.0.1:*", context=ctx)
    sub = Subscriber(pub.endpoint, [wire.topic_prefix("live")], context=ctx, on_error=lambda t, e: None)
    try:
        # wait until the subscription has reached the publisher (slow joiner)
        deadline = time.monotonic() + 5
        probe = SkeletonFrame("k", 0, 0, "kinect_v2", [])
        got = []
        while not got and time.monotonic() < deadline:
            pub.publish("live", probe)
            got = list(sub.receive(count=1, timeout_s=0.05))
        assert got, "subscription never reached the publisher"
        while list(sub.receive(count=1, timeout_s=0.1)):
            pass  # drain probes
        base = dict(sub.counters)
        J = KINECT_V2.n_joints
        good = [SkeletonFrame("k", s, s, "kinect_v2", [BodyFrame(1, np.zeros((J, 3)), np.ones(J))]) for s in range(1, 6)]
        topic = wire.topic_for("live", "k")
        pub.publish("live", good[0])
        pub.send_raw(topic, b"garbage")                                   # garbage
        pub.publish("live", good[1])
        pub.send_raw(topic, wire.encode_frame(good[2])[:-7])              # truncated
        pub.publish("live", good[2])
        pub.socket.send_multipart([topic, wire.encode_frame(good[3]), b"x"])  # 3 parts
        pub.send_raw(wire.topic_for("live", "other"), wire.encode_frame(good[3]))  # stream mismatch
        pub.publish("live", good[3])
        pub.send_raw(b"sf/live/", wire.encode_frame(good[4]))             # bad topic
        pub.publish("live", good[4])
        received = list(sub.receive(count=5, timeout_s=5))
        assert [r.message.seq for r in received] == [1, 2, 3, 4, 5]
        c = sub.counters
        assert c["malformed"] - base.get("malformed", 0) == 5
        assert c["garbage"] - base.get("garbage", 0) == 1
        assert c["truncated"] - base.get("truncated", 0) == 1
        assert c["parts"] - base.get("parts", 0) == 1
        assert c["topic"] - base.get("topic", 0) == 2
    finally:
        sub.close()
        pub.close()
        ctx.term()


def test_subscriber_learns_custom_skeleton_from_meta_topic():
    arm = Skeleton("loopback_arm", tuple("abcdefghi"), tuple((i, i + 1) for i in range(8)))
    with LoopbackPublisher(kind="clean", stream="arm", skeleton=arm) as lp:
        with Subscriber(lp.endpoint, [wire.topic_prefix("clean")], on_error=lambda t, e: None) as sub:
            frames = list(sub.receive(count=10, timeout_s=10))
    assert len(frames) == 10
    assert sub.skeletons["loopback_arm"] == arm
    assert sub.stream_info["arm"].rate_hz == 30.0
    seqs = [f.message.seq for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + 10)), "loopback delivery is in order and complete"
    for f in frames:
        body = f.message.bodies[0]
        want = expected_positions(f.message.seq, 1, 9)
        ok = np.arange(9) != MISSING_JOINT
        np.testing.assert_array_equal(body.positions[ok], want[ok])
        assert body.recovered[RECOVERED_JOINT] and body.recovered.sum() == 1


def test_python_reference_subscriber_reads_a_live_stream():
    with LoopbackPublisher(kind="live", garbage_every=4) as lp:
        proc = subprocess.run(
            [sys.executable, str(REFERENCE), "--connect", lp.endpoint, "--topic", "sf/live/",
             "--count", "12", "--timeout", "20"],
            capture_output=True, text=True, timeout=60,
        )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 12
    seqs = [int(line.split()[1].removeprefix("seq=")) for line in lines]
    assert seqs == list(range(seqs[0], seqs[0] + 12))
    for line in lines:
        # two bodies: 25 joints = 23 observed / 1 recovered / 1 missing
        assert line.startswith("sf/live/kinect0 ") and " bodies=2 1:23/1/1 4:23/1/1" in line
    assert "rejected" in proc.stderr  # the garbage was reported, not fatal
