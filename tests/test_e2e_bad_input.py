"""Bad input through a real ``streamfix serve``: each kind is counted by reason and skipped,
and every good frame around it still comes out on ``live`` and ``clean``.

A raw PUSH sender interleaves good Kinect v2 frames (from a real recording) with garbage
bytes, a truncated message, a wrong joint count, an unknown skeleton and a newer
protocol version; one good frame carries NaN/inf coordinates (missing joints, not an
error). The counts are read back from the Prometheus endpoint.
"""
from __future__ import annotations

import time

import msgpack
import numpy as np
import zmq

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.transport.wire import encode_frame, encode_skeleton_message, topic_for
from streamfix.skeletons import KINECT_V2

from test_e2e_harness import connect_and_wait, connected_subscriber, serve

ENGINE_ARGS = ("--engine", "streamfix")
STREAM = "bad-input"


def _frame(motion, i: int, seq: int, *, positions=None, skeleton="kinect_v2", confidence=None) -> SkeletonFrame:
    pos = motion.positions[i] if positions is None else positions
    conf = motion.confidence[i] if confidence is None else confidence
    return SkeletonFrame(
        stream_id=STREAM, seq=seq, sensor_time_ns=int(round(motion.timestamps[i] * 1e9)), skeleton=skeleton,
        bodies=[BodyFrame(0, np.array(pos, dtype=np.float64), np.array(conf, dtype=np.float64))],
    )


def test_each_bad_message_is_counted_and_skipped_good_frames_all_come_out(tmp_path, shared_data):
    motion = read_kinect_csv(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    n_good = 60
    good = [_frame(motion, i, i) for i in range(n_good)]
    # one good frame with NaN and inf coordinates on tracked joints: missing joints, not an error
    nan_seq = 20
    pos = motion.positions[nan_seq].copy()
    pos[3] = np.nan
    pos[7, 1] = np.inf
    pos[9, 2] = -np.inf
    good[nan_seq] = _frame(motion, nan_seq, nan_seq, positions=pos, confidence=np.ones(25))

    valid = encode_frame(good[0])
    newer = msgpack.unpackb(valid, raw=False)
    newer["v"] = 2
    wrong_joints = _frame(motion, 0, 999, positions=motion.positions[0][:24], confidence=np.ones(24))
    bad = {
        "garbage": [b"\x00\xff\xfe this is not msgpack \xc1", b""],
        "truncated": [valid[: len(valid) // 2]],
        "wrong_joint_count": [encode_frame(wrong_joints)],
        "unknown_skeleton": [encode_frame(_frame(motion, 0, 998, skeleton="no_such_skeleton"))],
        "newer_version": [msgpack.packb(newer, use_bin_type=True)],
    }
    topic = topic_for("raw", STREAM)
    plan: list[bytes] = []
    bad_iter = [(reason, payload) for reason, payloads in bad.items() for payload in payloads] * 2
    for i, f in enumerate(good):
        plan.append(encode_frame(f))
        if i % 4 == 1 and bad_iter:
            plan.append(bad_iter.pop(0)[1])
    assert not bad_iter, "every bad message must be sent between good ones"

    with serve(tmp_path, *ENGINE_ARGS) as sp:
        sub = connected_subscriber(sp.out, (b"sf/live/", b"sf/clean/"))
        ctx = zmq.Context.instance()
        push = ctx.socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 5000)
        try:
            connect_and_wait(push, sp.source)
            push.send_multipart([topic_for("meta", STREAM), encode_skeleton_message(KINECT_V2, 30.0, STREAM)])
            for payload in plan:
                push.send_multipart([topic, payload])
                time.sleep(0.002)
            seqs = {"live": [], "clean": []}
            deadline = time.monotonic() + 30
            # the last frames of the clean output wait for their lookahead: ask for the flush
            while time.monotonic() < deadline and len(seqs["live"]) < n_good:
                for r in sub.receive(timeout_s=0.5):
                    if not r.message.filled:
                        seqs[r.kind].append(r.message.seq)
                    if len(seqs["live"]) >= n_good:
                        break
            metrics = sp.metrics()
            assert sp.terminate() == 0
            for r in sub.receive(timeout_s=3.0):
                if not r.message.filled:
                    seqs[r.kind].append(r.message.seq)
        finally:
            push.close(linger=0)
            sub.close()

    expected = list(range(n_good))
    assert seqs["live"] == expected, "every good frame appears once on live, in order"
    assert seqs["clean"] == expected, "every good frame appears once on clean, in order"
    for reason, payloads in bad.items():
        assert metrics[f'streamfix_malformed_total{{reason="{reason}"}}'] == 2 * len(payloads), reason
    assert metrics['streamfix_malformed_total{reason="invalid"}'] == 0
    assert metrics["streamfix_nonfinite_joints_total"] == 3
    assert metrics[f'streamfix_frames_in_total{{stream="{STREAM}"}}'] == n_good
    log = sp.stderr
    for reason, payloads in bad.items():
        lines = [ln for ln in log.splitlines() if f"skipped malformed input ({reason})" in ln]
        assert len(lines) == 2 * len(payloads), (reason, lines)
