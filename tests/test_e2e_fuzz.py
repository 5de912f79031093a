"""Fuzzing a real ``streamfix serve``: 50,000+ hostile messages, then a valid stream exactly.

The messages (seeded, so a failure reproduces) mix five classes: random bytes;
valid frame and skeleton payloads with bytes flipped, cut or appended; valid maps with
one field replaced by a hostile value (uint64 edges, negative, NaN, huge floats,
megabyte-long strings, nested containers, wrong types); ZeroMQ messages with the wrong
number of parts or bad topics; and msgpack bombs (deep nesting, huge declared lengths,
maps of thousands of keys). They go through a real PUSH socket on 127.0.0.1 into the
service's real PULL socket and decoder, validation, limits and the default streaming
engine. Afterwards the service must be alive, must have counted what it refused, and
a known valid stream (a real Kinect v2 recording) must come out exactly on ``live``
and ``clean``.
"""
from __future__ import annotations

import random
import time

import msgpack
import zmq

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.skeletons import KINECT_V2
from streamfix.transport.wire import encode_frame, encode_skeleton_message, topic_for

from test_e2e_harness import connect_and_wait, connected_subscriber, serve

N_MESSAGES = 50_000
ENGINE = ("--engine", "streamfix")
HOSTILE = [0, -1, 1, 2**63 - 1, 2**63, 2**64 - 1, -(2**63), 1e308, -1e308, float("nan"), float("inf"), 3e38,
           "", "x" * 70, "kinect_v2", "arm3", "y" * 200_000, b"", b"\x00" * 301, b"\xff" * 1200, [], [[]] * 50,
           {}, {"id": 1}, [{"id": 1, "pos": b"\x00" * 300, "conf": b"\x00" * 100}] * 65, None, True, 1e-300]


def _seed_payloads(motion) -> list[dict]:
    """Valid decoded maps to mutate: frames (one and several bodies) and skeleton messages."""
    maps = []
    for i in range(4):
        bodies = [BodyFrame(b, motion.positions[i], motion.confidence[i]) for b in range(1 + i)]
        maps.append(msgpack.unpackb(encode_frame(SkeletonFrame(f"fz{i}", 2**64 - 5 + i, i * 33_333_333,
                                                               "kinect_v2", bodies)), raw=False))
    maps.append(msgpack.unpackb(encode_skeleton_message(KINECT_V2, 30.0, "fzmeta"), raw=False))
    return maps


def _messages(seed_maps: list[dict], n: int, rng: random.Random) -> list[list[bytes]]:
    packed = [msgpack.packb(m, use_bin_type=True) for m in seed_maps]
    bombs = [b"\x91" * 60_000 + b"\xc0", b"\xdd\xff\xff\xff\xff", b"\xdf\xff\xff\xff\xff",
             msgpack.packb({str(k): k for k in range(20_000)}), msgpack.packb([[[[[]]]]] * 40_000),
             b"\xc6\xff\xff\xff\xff" + b"\x00" * 16, msgpack.packb({"v": 1, "type": "frame", "bodies": [[]] * 60_000})]
    out: list[list[bytes]] = []
    for k in range(n):
        cls = k % 10
        stream = f"fz{rng.randrange(8)}"
        topic = topic_for("raw", stream)
        if cls < 4:  # random bytes
            payload = rng.randbytes(rng.randrange(0, 400))
        elif cls < 6:  # byte-level mutations of valid payloads
            b = bytearray(rng.choice(packed))
            for _ in range(rng.randrange(1, 9)):
                op = rng.randrange(3)
                if op == 0 and b:
                    b[rng.randrange(len(b))] = rng.randrange(256)
                elif op == 1 and b:
                    del b[rng.randrange(len(b)):]
                else:
                    b.extend(rng.randbytes(rng.randrange(1, 20)))
            payload = bytes(b)
        elif cls < 9 and k % 20 < 18:  # structure-level: one field replaced by a hostile value
            m = dict(rng.choice(seed_maps))
            m["stream"] = stream if m["type"] == "frame" else f"m{stream}"  # meta of other streams
            key = rng.choice(list(m) + ["bodies", "seq", "t_sensor_ns", "rate_hz", "joint_names", "extra"])
            m[key] = rng.choice(HOSTILE)
            if key == "bodies" and rng.random() < 0.5 and m.get("type") == "frame":
                m["bodies"] = [dict(b, id=rng.choice(HOSTILE[:8])) for b in seed_maps[3]["bodies"]]
            try:
                payload = msgpack.packb(m, use_bin_type=True)
            except (OverflowError, ValueError, TypeError):
                payload = b"\xc1"
            if m.get("type") == "skeleton":
                topic = b"sf/meta/" + (m["stream"] if isinstance(m["stream"], str) else "x").encode()[:100]
        elif cls < 9 or k % 20 == 9:  # wrong number of parts, bad topics
            out.append(rng.choice([[b"sf/raw/x", b"", b""], [b"\x00" * 5000, packed[0]], [b"sf/raw/" + b"z" * 90, packed[0]],
                                   [], [b"sf/meta/fz1", packed[0]]]) or [b""])
            continue
        else:  # msgpack bombs
            payload = rng.choice(bombs)
        out.append([topic, payload])
    return out


def test_fuzzed_input_is_survived_and_counted_then_a_valid_stream_comes_through_exactly(tmp_path, shared_data):
    motion = read_kinect_csv(shared_data / "kinect_v2" / "Ges04_comehere.csv")
    rng = random.Random(20261122)
    messages = _messages(_seed_payloads(motion), N_MESSAGES, rng)
    assert len(messages) >= N_MESSAGES
    with serve(tmp_path, "--idle-timeout", "0.5", "--log-level", "ERROR", *ENGINE) as sp:
        sub = connected_subscriber(sp.out, (b"sf/live/good", b"sf/clean/good"))
        push = zmq.Context.instance().socket(zmq.PUSH)
        push.setsockopt(zmq.LINGER, 0)
        push.setsockopt(zmq.SNDHWM, 0)
        got = {"live": [], "clean": []}
        try:
            connect_and_wait(push, sp.source)
            t0 = time.monotonic()
            for parts in messages:
                push.send_multipart(parts)
            # the fuzzed streams hold every stream slot until they go idle and are reclaimed
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                m = sp.metrics()
                if m["streamfix_streams"] == 0 and m["streamfix_input_backlog_frames"] == 0:
                    break
                assert sp.proc.poll() is None, sp.stderr[-3000:]
                time.sleep(0.2)
            took = time.monotonic() - t0
            n_good = 60
            push.send_multipart([topic_for("meta", "good"), encode_skeleton_message(KINECT_V2, 30.0, "good")])
            for i in range(n_good):
                f = SkeletonFrame("good", i, int(round(motion.timestamps[i] * 1e9)), "kinect_v2",
                                  [BodyFrame(0, motion.positions[i], motion.confidence[i])])
                push.send_multipart([topic_for("raw", "good"), encode_frame(f)])
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and sum(not m.filled for m in got["clean"]) < n_good:
                for r in sub.receive(timeout_s=0.5):
                    got[r.kind].append(r.message)
                assert sp.proc.poll() is None, sp.stderr[-3000:]
            m = sp.metrics()
            status = open(f"/proc/{sp.proc.pid}/status").read()
            assert sp.terminate() == 0, sp.stderr[-3000:]
        finally:
            push.close(linger=0)
            sub.close()
    rss_kb = int(status.split("VmRSS:")[1].split()[0])
    print(f"fuzz: {len(messages)} messages handled in {took:.1f} s; RSS {rss_kb / 1024:.0f} MB; "
          f"restarts {sum(v for k, v in m.items() if k.startswith('streamfix_stream_restarts_total'))}, "
          f"frames in {sum(v for k, v in m.items() if k.startswith('streamfix_frames_in_total'))}")
    malformed = sum(v for k, v in m.items() if k.startswith("streamfix_malformed_total"))
    limits = sum(v for k, v in m.items() if k.startswith("streamfix_limit_hits_total"))
    assert malformed > 0.5 * N_MESSAGES and limits > 0, (malformed, limits)
    assert rss_kb < 500 * 1024
    for kind in ("live", "clean"):
        real = [f for f in got[kind] if not f.filled]
        assert [f.sensor_time_ns for f in real] == [int(round(motion.timestamps[i] * 1e9)) for i in range(n_good)]
        seqs = [f.seq for f in got[kind]]
        assert seqs == list(range(len(seqs))), kind
    assert "Traceback" not in sp.stderr
