"""A stalled subscriber neither stalls ``streamfix serve`` nor grows its memory without bound.

One SUB connects to everything and never reads (tiny kernel buffer); a healthy SUB
reads ``clean``. Many frames are pushed as fast as the service takes them. The
healthy subscriber must still get every frame in order (the service kept going and
the stalled peer cost the others nothing), and the service's resident memory after
warm-up may grow by far less than what queueing everything for the stalled peer
would take. Frames use a 200-joint skeleton (announced by a skeleton message) so that
queueing everything for the stalled peer would be ~3.4 kB x 3 topics per frame.
"""
from __future__ import annotations

import threading
import time

import numpy as np
import zmq

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.skeletons import Skeleton
from streamfix.transport.wire import decode_frame, encode_frame, encode_skeleton_message, topic_for

from test_e2e_harness import connect_and_wait, serve

ENGINE_ARGS = ("--engine", "passthrough")
N_FRAMES = 6000
WARMUP = 1000
MAX_GROWTH_MB = 10.0
N_JOINTS = 200


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS")


def test_stalled_subscriber_does_not_stall_service_or_grow_its_memory(tmp_path):
    skeleton = Skeleton("chain200", tuple(f"j{i}" for i in range(N_JOINTS)),
                        tuple((i, i + 1) for i in range(N_JOINTS - 1)))
    base = np.stack([np.zeros(N_JOINTS), np.linspace(0, 2, N_JOINTS), np.full(N_JOINTS, 2.5)], axis=1)
    conf = np.ones(N_JOINTS)
    payloads = []
    for k in range(N_FRAMES):
        pos = base + 0.01 * np.sin(0.1 * k + np.arange(N_JOINTS))[:, None]
        payloads.append(encode_frame(SkeletonFrame("slow", k, int(k * 1e9 / 30), skeleton.name,
                                                   [BodyFrame(0, pos, conf)])))
    payload_bytes = len(payloads[0])
    ctx = zmq.Context.instance()
    with serve(tmp_path, *ENGINE_ARGS) as sp:
        stalled = ctx.socket(zmq.SUB)
        stalled.setsockopt(zmq.RCVHWM, 10)
        stalled.setsockopt(zmq.RCVBUF, 4096)
        stalled.setsockopt(zmq.SUBSCRIBE, b"")
        healthy = ctx.socket(zmq.SUB)
        healthy.setsockopt(zmq.RCVHWM, 0)
        healthy.setsockopt(zmq.SUBSCRIBE, b"sf/clean/")
        push = ctx.socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 0)
        push.connect(sp.source)
        stop = threading.Event()

        def send() -> None:
            push.send_multipart([topic_for("meta", "slow"), encode_skeleton_message(skeleton, 30.0, "slow")])
            topic = topic_for("raw", "slow")
            for p in payloads:
                while not stop.is_set():
                    try:
                        push.send_multipart([topic, p], zmq.NOBLOCK)
                        break
                    except zmq.Again:  # the service pushes back: wait, lose nothing
                        time.sleep(0.001)
                if stop.is_set():
                    return

        try:
            connect_and_wait(stalled, sp.out)
            connect_and_wait(healthy, sp.out)
            sender = threading.Thread(target=send, daemon=True)
            sender.start()
            seqs: list[int] = []
            warm_rss = None
            deadline = time.monotonic() + 60
            while len(seqs) < N_FRAMES and time.monotonic() < deadline:
                if not healthy.poll(500):
                    continue
                topic, payload = healthy.recv_multipart()
                seqs.append(decode_frame(payload, {skeleton.name: skeleton}).seq)
                if len(seqs) == WARMUP:
                    warm_rss = rss_mb(sp.proc.pid)
            end_rss = rss_mb(sp.proc.pid)
            assert sp.proc.poll() is None, "the service must still be running"
            metrics = sp.metrics()
        finally:
            stop.set()
            for s in (push, stalled, healthy):
                s.close(linger=0)
    assert seqs == list(range(N_FRAMES)), (
        f"healthy subscriber got {len(seqs)} of {N_FRAMES} frames (in order: {seqs == sorted(seqs)})"
    )
    assert metrics['streamfix_frames_in_total{stream="slow"}'] == N_FRAMES
    unbounded_mb = (N_FRAMES - WARMUP) * 3 * payload_bytes / 2**20
    growth = end_rss - warm_rss
    assert growth < MAX_GROWTH_MB < unbounded_mb, (
        f"service RSS grew {growth:.1f} MB after warm-up (queueing everything would be ~{unbounded_mb:.0f} MB)"
    )
