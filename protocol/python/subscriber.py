#!/usr/bin/env python3
"""Reference subscriber for the streamfix wire protocol v1 (see ../SPEC.md).

Standalone: needs only ``pyzmq`` and ``msgpack`` (no numpy, no streamfix), so it is
what an outside user copies. It decodes and validates messages exactly as SPEC.md
section 6 says, and has two modes:

    python subscriber.py --vectors ../vectors
        decode every test vector and check it against its .json meaning; invalid
        vectors must be rejected with the stated reason. Exit 1 on any mismatch.

    python subscriber.py --connect tcp://127.0.0.1:5556 [--topic sf/live/] [--count N] [--timeout S]
        subscribe and print one line per frame (skeleton messages go to stderr):
        <topic> seq=<n> t_sensor_ns=<t> bodies=<k> [id:observed/recovered/missing ...] [filled]
        exit 0 once N frames were printed, 2 if the timeout came first.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import struct
import sys
import time
from pathlib import Path

import msgpack
import zmq

SUPPORTED_VERSION = 1
STREAM_RE = re.compile(r"^[A-Za-z0-9_.:\-]{1,64}$")
KINDS = ("raw", "live", "clean", "meta")

# Built-in skeletons: name -> joint count (layouts arrive in skeleton messages).
BUILTIN_JOINTS = {"kinect_v2": 25, "azure_kinect": 32, "mediapipe_pose": 33}


class Rejected(Exception):
    """A message a subscriber must skip; ``reason`` is the SPEC.md section 6 key."""

    def __init__(self, reason: str, text: str) -> None:
        super().__init__(f"{reason}: {text}")
        self.reason = reason


def _int(m: dict, key: str, minimum: int | None = None) -> int:
    v = m.get(key)
    if not isinstance(v, int) or isinstance(v, bool):
        raise Rejected("field", f"{key!r} missing or not an integer")
    if minimum is not None and v < minimum:
        raise Rejected("field", f"{key!r} is {v}, below {minimum}")
    return v


def _int64(m: dict, key: str) -> int:
    v = _int(m, key)
    if not -(2**63) <= v < 2**63:
        raise Rejected("field", f"{key!r} is {v}, outside the signed 64-bit range")
    return v


def _str(m: dict, key: str) -> str:
    v = m.get(key)
    if not isinstance(v, str):
        raise Rejected("field", f"{key!r} missing or not a string")
    return v


def unpack(payload: bytes) -> dict:
    """msgpack -> map, with the version check; Rejected otherwise."""
    if not payload:
        raise Rejected("garbage", "empty payload")
    try:
        m = msgpack.unpackb(payload, raw=False)
    except msgpack.ExtraData:
        raise Rejected("garbage", "bytes after the msgpack value") from None
    except ValueError as exc:  # msgpack raises ValueError("Unpack failed: incomplete input")
        if "incomplete" in str(exc):
            raise Rejected("truncated", "payload ends inside a value") from None
        raise Rejected("garbage", f"not msgpack: {exc}") from None
    except Exception as exc:
        raise Rejected("garbage", f"not msgpack: {type(exc).__name__}") from None
    if not isinstance(m, dict):
        raise Rejected("garbage", "payload is not a map")
    v = _int(m, "v")
    if v > SUPPORTED_VERSION or v < 1:
        raise Rejected("version", f"protocol version {v}, this subscriber supports 1..{SUPPORTED_VERSION}")
    return m


def floats(blob: bytes) -> list[float]:
    return list(struct.unpack(f"<{len(blob) // 4}f", blob))


def decode(payload: bytes, skeletons: dict[str, dict]) -> dict:
    """Decode a payload into the plain meaning used by the vector .json files.

    ``skeletons``: name -> decoded skeleton message (built-in names need none).
    Skeleton messages decoded here are added to it.
    """
    m = unpack(payload)
    mtype = _str(m, "type")
    if mtype == "skeleton":
        return decode_skeleton(m, skeletons)
    if mtype != "frame":
        raise Rejected("type", f"unknown message type {mtype!r}")
    stream = _str(m, "stream")
    if not STREAM_RE.match(stream):
        raise Rejected("field", f"bad stream id {stream!r}")
    seq = _int(m, "seq", 0)
    t_sensor = _int64(m, "t_sensor_ns")
    t_pub = _int64(m, "t_publish_ns")
    name = _str(m, "skeleton")
    joints = _int(m, "joints", 0)
    filled = m.get("filled")
    if not isinstance(filled, bool):
        raise Rejected("field", "'filled' missing or not a boolean")
    bodies = m.get("bodies")
    if not isinstance(bodies, list):
        raise Rejected("field", "'bodies' missing or not an array")
    if len(bodies) > 64:
        raise Rejected("field", "more than 64 bodies")
    if name in skeletons:
        n_joints = len(skeletons[name]["joint_names"])
    elif name in BUILTIN_JOINTS:
        n_joints = BUILTIN_JOINTS[name]
    else:
        raise Rejected("skeleton", f"unknown skeleton {name!r}")
    if bodies and joints != n_joints:
        raise Rejected("joints", f"'joints' is {joints}, skeleton {name!r} has {n_joints}")
    out_bodies, ids = [], set()
    for b in bodies:
        if not isinstance(b, dict):
            raise Rejected("field", "body is not a map")
        bid = _int64(b, "id")
        if bid in ids:
            raise Rejected("field", f"duplicate body id {bid}")
        ids.add(bid)
        blobs = {}
        for key, size, required in (("pos", 12 * n_joints, True), ("conf", 4 * n_joints, True), ("rec", n_joints, False)):
            blob = b.get(key)
            if blob is None and not required:
                continue
            if not isinstance(blob, bytes):
                raise Rejected("field", f"body {bid}: {key!r} missing or not binary")
            if len(blob) != size:
                raise Rejected("joints", f"body {bid}: {key!r} has {len(blob)} bytes, expected {size}")
            blobs[key] = blob
        xyz = floats(blobs["pos"])
        conf = [0.0 if math.isnan(c) else min(1.0, max(0.0, c)) for c in floats(blobs["conf"])]
        positions = []
        for j in range(n_joints):
            p = xyz[3 * j: 3 * j + 3]
            if all(math.isfinite(c) for c in p):
                positions.append(p)
            else:  # NaN/inf coordinate: a missing joint, not an error
                positions.append(None)
                conf[j] = 0.0
        rec = blobs.get("rec")
        out_bodies.append({
            "id": bid,
            "positions": positions,
            "confidence": conf,
            "recovered": None if rec is None else [x != 0 for x in rec],
        })
    out = {"type": "frame", "stream": stream, "seq": seq, "t_sensor_ns": t_sensor,
           "t_publish_ns": t_pub, "skeleton": name, "joints": joints, "filled": filled,
           "bodies": out_bodies}
    for key in ("epoch", "dropped"):  # optional (SPEC 4.1)
        if key in m:
            value = _int(m, key, 0)
            if value >= 2**64:
                raise Rejected("field", f"{key!r} is {value}, outside the unsigned 64-bit range")
            if value:
                out[key] = value
    return out


def decode_skeleton(m: dict, skeletons: dict[str, dict]) -> dict:
    stream = _str(m, "stream")
    if not STREAM_RE.match(stream):
        raise Rejected("field", f"bad stream id {stream!r}")
    name = _str(m, "skeleton")
    names = m.get("joint_names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
        raise Rejected("field", "'joint_names' is not an array of distinct strings")
    bones = m.get("bones")
    if not isinstance(bones, list):
        raise Rejected("field", "'bones' missing or not an array")
    for bone in bones:
        ok = (isinstance(bone, list) and len(bone) == 2
              and all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(names) for i in bone)
              and bone[0] != bone[1])
        if not ok:
            raise Rejected("field", f"bone {bone!r} does not join two of the {len(names)} joints")
    rate = m.get("rate_hz")
    if not isinstance(rate, (int, float)) or isinstance(rate, bool) or not rate > 0 or not math.isfinite(rate):
        raise Rejected("field", "'rate_hz' missing or not a positive number")
    if m.get("units") != "m":
        raise Rejected("field", "'units' is not 'm'")
    t_pub = _int64(m, "t_publish_ns") if "t_publish_ns" in m else 0
    msg = {"type": "skeleton", "stream": stream, "skeleton": name, "joint_names": names,
           "bones": bones, "rate_hz": float(rate), "units": "m", "t_publish_ns": t_pub}
    skeletons[name] = msg
    return msg


def check_vectors(directory: Path) -> int:
    index = json.loads((directory / "index.json").read_text())
    skeletons: dict[str, dict] = {}
    failures = 0
    for name in index["vectors"]:
        meta = json.loads((directory / f"{name}.json").read_text())
        payload = (directory / f"{name}.bin").read_bytes()
        try:
            got = decode(payload, skeletons)
        except Rejected as exc:
            if meta["valid"]:
                print(f"FAIL {name}: valid vector rejected ({exc})")
                failures += 1
            elif exc.reason != meta["reason"]:
                print(f"FAIL {name}: rejected for {exc.reason!r}, expected {meta['reason']!r}")
                failures += 1
            else:
                print(f"ok   {name}: rejected ({exc})")
            continue
        if not meta["valid"]:
            print(f"FAIL {name}: invalid vector accepted")
            failures += 1
        elif got != meta["message"]:
            print(f"FAIL {name}: decoded meaning differs from {name}.json")
            failures += 1
        else:
            print(f"ok   {name}")
    print(f"{len(index['vectors']) - failures}/{len(index['vectors'])} vectors ok")
    return 1 if failures else 0


def describe(topic: str, msg: dict) -> str:
    if msg["type"] == "skeleton":
        return (f"{topic} skeleton={msg['skeleton']} joints={len(msg['joint_names'])} "
                f"bones={len(msg['bones'])} rate_hz={msg['rate_hz']:g}")
    parts = [f"{topic} seq={msg['seq']} t_sensor_ns={msg['t_sensor_ns']} bodies={len(msg['bodies'])}"]
    for b in msg["bodies"]:
        missing = sum(p is None for p in b["positions"])
        rec = sum(b["recovered"] or [])
        parts.append(f"{b['id']}:{len(b['positions']) - missing - rec}/{rec}/{missing}")
    if msg["filled"]:
        parts.append("filled")
    if msg.get("dropped"):
        parts.append(f"dropped={msg['dropped']}")
    return " ".join(parts)


def subscribe(endpoint: str, topics: list[str], count: int | None, timeout_s: float | None) -> int:
    ctx = zmq.Context()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    for t in set(topics) | {"sf/meta/"}:  # always learn skeletons
        sock.setsockopt(zmq.SUBSCRIBE, t.encode())
    sock.connect(endpoint)
    skeletons: dict[str, dict] = {}
    printed = rejected = 0
    last_seq: dict[str, tuple[int, int]] = {}  # topic -> (epoch, seq)
    gaps = restarts = 0
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    try:
        while count is None or printed < count:
            wait = 500 if deadline is None else int(max(0.0, deadline - time.monotonic()) * 1000)
            if deadline is not None and wait <= 0:
                break
            if not sock.poll(min(wait, 500)):
                continue
            parts = sock.recv_multipart()
            if len(parts) != 2:
                rejected += 1
                print(f"rejected: parts: {len(parts)} frames, expected 2", file=sys.stderr)
                continue
            topic = parts[0].decode("ascii", "replace")
            fields = topic.split("/")
            if len(fields) != 3 or fields[0] != "sf" or fields[1] not in KINDS:
                rejected += 1
                print(f"rejected: topic: {topic!r}", file=sys.stderr)
                continue
            try:
                msg = decode(parts[1], skeletons)
            except Rejected as exc:
                if exc.reason != "type":
                    rejected += 1
                print(f"rejected on {topic}: {exc}", file=sys.stderr)
                continue
            if msg["stream"] != fields[2] or (msg["type"] == "skeleton") != (fields[1] == "meta"):
                rejected += 1
                print(f"rejected: topic: {msg['type']} for {msg['stream']!r} on {topic!r}", file=sys.stderr)
                continue
            if msg["type"] == "skeleton":
                print(describe(topic, msg), file=sys.stderr)
                continue
            if not any(topic.startswith(t) for t in topics):
                continue
            prev = last_seq.get(topic)
            epoch = msg.get("epoch", 0)
            if prev is not None and prev[0] != epoch:
                restarts += 1  # the service restarted this stream's numbering: not a gap, not reordering
            elif prev is not None and msg["seq"] != prev[1] + 1:
                gaps += 1  # lost on the way (slow joiner / high-water mark)
            last_seq[topic] = (epoch, msg["seq"])
            print(describe(topic, msg), flush=True)
            printed += 1
    finally:
        sock.close()
        ctx.term()
    print(f"{printed} frames, {rejected} rejected, {gaps} sequence gaps, {restarts} epoch changes", file=sys.stderr)
    return 0 if count is None or printed >= count else 2


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="streamfix protocol v1 reference subscriber")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--vectors", type=Path, help="check every test vector in DIR")
    mode.add_argument("--connect", help="endpoint of a streamfix PUB, e.g. tcp://127.0.0.1:5556")
    parser.add_argument("--topic", action="append", help="topic prefix (repeatable; default sf/)")
    parser.add_argument("--count", type=int, help="stop after N frames")
    parser.add_argument("--timeout", type=float, help="stop after S seconds")
    args = parser.parse_args(argv)
    if args.vectors:
        return check_vectors(args.vectors)
    return subscribe(args.connect, args.topic or ["sf/"], args.count, args.timeout)


if __name__ == "__main__":
    sys.exit(main())
