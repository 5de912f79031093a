"""``streamfix tap`` against a real loopback publisher (bounded count and timeout)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from test_e2e_harness import free_port
from test_protocol_live import MISSING_JOINT, RECOVERED_JOINT, LoopbackPublisher, expected_positions

from streamfix.skeletons import KINECT_V2


def _tap(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamfix", "tap", *args],
                          capture_output=True, text=True, timeout=timeout)


def test_tap_json_prints_decoded_frames_and_reports_garbage():
    with LoopbackPublisher(kind="live", garbage_every=2) as lp:
        proc = _tap(lp.endpoint, "--topic", "live", "--count", "6", "--json", "--duration", "20")
    assert proc.returncode == 0, proc.stderr
    objs = [json.loads(line) for line in proc.stdout.splitlines()]
    assert len(objs) == 6
    seqs = [o["seq"] for o in objs]
    assert seqs == list(range(seqs[0], seqs[0] + 6))
    J = KINECT_V2.n_joints
    for o in objs:
        assert o["topic"] == "sf/live/kinect0" and o["stream"] == "kinect0" and o["kind"] == "live"
        assert o["type"] == "frame" and o["skeleton"] == "kinect_v2" and o["filled"] is False
        assert o["t_sensor_ns"] == o["seq"] * 33_333_333 and o["t_publish_ns"] > 0
        assert [b["id"] for b in o["bodies"]] == [1, 4]
        for b in o["bodies"]:
            joints = b["joints"]
            assert len(joints) == J and joints[MISSING_JOINT] is None and b["confidence"][MISSING_JOINT] == 0
            want = expected_positions(o["seq"], b["id"], J)
            got = np.array([j if j is not None else [np.nan] * 3 for j in joints])
            ok = np.arange(J) != MISSING_JOINT
            np.testing.assert_array_equal(got[ok], want[ok])
            assert b["recovered"][RECOVERED_JOINT] is True and sum(b["recovered"]) == 1
    assert "skipped message on 'sf/live/kinect0' (garbage)" in proc.stderr
    assert "malformed" in proc.stderr


def test_tap_meta_prints_skeleton_messages():
    with LoopbackPublisher(kind="live") as lp:
        proc = _tap(lp.endpoint, "--topic", "meta", "--count", "1", "--json", "--duration", "20")
    assert proc.returncode == 0, proc.stderr
    obj = json.loads(proc.stdout.splitlines()[0])
    assert obj["type"] == "skeleton" and obj["topic"] == "sf/meta/kinect0"
    assert obj["joint_names"] == list(KINECT_V2.joint_names)
    assert [tuple(b) for b in obj["bones"]] == list(KINECT_V2.bones) and obj["units"] == "m"


def test_tap_topic_filters_and_times_out_with_exit_2():
    with LoopbackPublisher(kind="live") as lp:
        proc = _tap(lp.endpoint, "--topic", "clean", "--count", "1", "--duration", "1")
        assert proc.returncode == 2 and proc.stdout == ""
        assert "0 printed" in proc.stderr
        # a raw prefix works as well, and the plain text form has one line per frame
        proc = _tap(lp.endpoint, "--topic", "sf/live/kin", "--count", "3", "--duration", "20")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert len(lines) == 3 and all(line.startswith("sf/live/kinect0 seq=") for line in lines)
    assert all(" bodies=2 1:23/1/1 4:23/1/1 " in line for line in lines)  # observed/recovered/missing


def test_tap_bind_pull_loses_nothing_sent_before_it_started():
    """SPEC section 1: a connecting PUSH queues frames until the PULL side is up."""
    import zmq

    from streamfix.transport.zmq_io import FramePublisher

    endpoint = f"tcp://127.0.0.1:{free_port()}"
    lp = LoopbackPublisher(kind="raw")  # only for its deterministic frames
    lp.pub.close()
    push = FramePublisher(endpoint, bind=False, socket_type=zmq.PUSH)
    try:
        push.announce("kinect0", KINECT_V2, 30.0)
        for seq in range(20):  # all sent before anybody listens
            push.publish("raw", lp.frame(seq))
            if seq in (3, 7):  # a PULL socket gets every topic: these the filter leaves out, not malformed
                push.publish("live", lp.frame(seq))
        proc = _tap(endpoint, "--bind", "--topic", "raw", "--count", "20", "--json", "--duration", "20")
    finally:
        push.socket.setsockopt(zmq.LINGER, 0)
        push.close()
    assert proc.returncode == 0, proc.stderr
    assert [json.loads(line)["seq"] for line in proc.stdout.splitlines()] == list(range(20))
    assert "0 malformed, 0 unknown type, 2 on other topics" in proc.stderr, proc.stderr
