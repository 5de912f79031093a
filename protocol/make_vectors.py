#!/usr/bin/env python3
"""Generate the protocol test vectors in ``protocol/vectors/`` (see SPEC.md section 8).

Valid vectors are encoded with ``streamfix.transport.wire``; their ``.json`` meaning
is computed from the *input* values (rounded to float32, non-finite -> null), not
from the decoder, so a decoder bug shows up as a mismatch. Invalid vectors are valid
messages broken in one stated way; each must be rejected with the stated reason
(this script refuses to write a vector the wire module accepts or rejects for a
different reason).

    python protocol/make_vectors.py            # rewrite protocol/vectors/
    python protocol/make_vectors.py --out DIR  # write elsewhere (the drift test does)
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import msgpack
import numpy as np

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.skeletons import KINECT_V2, Skeleton, get_skeleton
from streamfix.transport import wire

HERE = Path(__file__).resolve().parent
T0 = 1_700_000_000_000_000_000  # a fixed wall clock for t_publish_ns (ns)
CUSTOM = Skeleton("demo_arm", ("shoulder", "elbow", "wrist", "hand"), ((0, 1), (1, 2), (2, 3)))


def _pose(rng: np.random.Generator, n_joints: int, offset: float = 0.0) -> np.ndarray:
    """A deterministic body-sized point cloud in metres (values exact in float32)."""
    base = np.array([offset, 0.9, 2.5]) + rng.uniform(-0.6, 0.6, size=(n_joints, 3))
    return base.astype(np.float32).astype(np.float64)


def _json_floats(a: np.ndarray) -> list:
    """Float32-rounded values as JSON numbers; non-finite -> None (null)."""
    a32 = np.asarray(a, dtype=np.float64).astype(np.float32)
    out = a32.astype(np.float64).tolist()

    def fix(x):
        if isinstance(x, list):
            return [fix(y) for y in x]
        return x if np.isfinite(x) else None

    return fix(out)


def _frame_meaning(frame: SkeletonFrame) -> dict:
    """What a correct decoder must produce, from the frame's input values."""
    bodies = []
    for b in frame.bodies:
        pos = np.asarray(b.positions, dtype=np.float64).astype(np.float32).astype(np.float64)
        conf = np.asarray(b.confidence, dtype=np.float64).astype(np.float32).astype(np.float64)
        missing = ~np.isfinite(pos).all(axis=1)
        positions = _json_floats(pos)
        positions = [None if m else p for p, m in zip(positions, missing)]
        conf = np.clip(np.nan_to_num(conf, nan=0.0), 0.0, 1.0)
        conf[missing] = 0.0
        bodies.append({
            "id": int(b.body_id),
            "positions": positions,
            "confidence": conf.tolist(),
            "recovered": None if b.recovered is None else [bool(x) for x in b.recovered],
        })
    return {
        "type": "frame",
        "stream": frame.stream_id,
        "seq": int(frame.seq),
        "t_sensor_ns": int(frame.sensor_time_ns),
        "t_publish_ns": int(frame.publish_time_ns),
        "skeleton": frame.skeleton,
        "joints": len(frame.bodies[0].positions) if frame.bodies else get_skeleton(frame.skeleton).n_joints,
        "filled": bool(frame.filled),
        "bodies": bodies,
        # optional keys (SPEC 4.1): in the meaning only when the message carries them
        **({"epoch": int(frame.epoch)} if frame.epoch else {}),
        **({"dropped": int(frame.dropped)} if frame.dropped else {}),
    }


def _skeleton_meaning(skel: Skeleton, rate_hz: float, stream: str, t_pub: int) -> dict:
    return {
        "type": "skeleton",
        "stream": stream,
        "skeleton": skel.name,
        "joint_names": list(skel.joint_names),
        "bones": [list(b) for b in skel.bones],
        "rate_hz": float(rate_hz),
        "units": "m",
        "t_publish_ns": t_pub,
    }


def build_vectors() -> list[dict]:
    """Every vector as ``{name, valid, description, topic, payload, message|reason, ...}``."""
    rng = np.random.default_rng(20240531)
    J = KINECT_V2.n_joints
    vectors: list[dict] = []

    def valid_frame(name, kind, frame, description, requires=None, skeletons=None):
        payload = wire.encode_frame(frame)
        v = {"name": name, "valid": True, "description": description,
             "topic": wire.topic_for(kind, frame.stream_id).decode(),
             "payload": payload, "message": _frame_meaning(frame)}
        if requires:
            v["requires"] = requires
        vectors.append(v)
        return payload

    # --- valid frames
    conf = np.ones(J)
    conf[[13, 14, 15]] = 0.5  # inferred legs
    f = SkeletonFrame("kinect0", 0, 1_000_000_000, "kinect_v2",
                      [BodyFrame(7, _pose(rng, J), conf)], publish_time_ns=T0)
    good = valid_frame("frame_raw_one_body", "raw", f,
                       "raw Kinect v2 frame, one body, three inferred joints (confidence 0.5), no rec")

    pos = _pose(rng, J)
    pos[[7, 11]] = np.nan          # hands not seen
    pos[21, 0] = np.inf            # one inf coordinate: also a missing joint
    pos[23, 2] = -np.inf
    conf = np.ones(J)
    conf[[7, 11]] = 0.0
    f = SkeletonFrame("kinect0", 1, 1_033_333_333, "kinect_v2",
                      [BodyFrame(7, pos, conf)], publish_time_ns=T0 + 33_333_333)
    valid_frame("frame_missing_joints", "raw", f,
                "joints 7 and 11 NaN (confidence 0); joints 21 and 23 have an inf coordinate "
                "and confidence 1 on the wire: they decode as missing (null, confidence 0)")

    bodies = []
    for k, bid in enumerate((1, 4, 9)):
        rec = np.zeros(J, bool)
        rec[rng.choice(J, size=3 + k, replace=False)] = True
        c = np.where(rec, 0.0, 1.0)
        c[rec] = 0.25
        bodies.append(BodyFrame(bid, _pose(rng, J, offset=k - 1.0), c, rec))
    f = SkeletonFrame("kinect0", 41, 2_366_666_666, "kinect_v2", bodies, publish_time_ns=T0 + 2)
    valid_frame("frame_clean_three_bodies", "clean", f,
                "cleaned output with three bodies (ids 1, 4, 9) and recovered joints marked in rec")

    rec = np.ones(J, bool)
    f = SkeletonFrame("kinect0", 42, 2_400_000_000, "kinect_v2",
                      [BodyFrame(1, _pose(rng, J), np.full(J, 0.25), rec)],
                      publish_time_ns=T0 + 3, filled=True)
    valid_frame("frame_live_filled", "live", f,
                "a frame the service synthesised for a dropped sensor frame: filled=true, every joint recovered")

    f = SkeletonFrame("kinect0", 43, 2_433_333_333, "kinect_v2", [], publish_time_ns=T0 + 4)
    valid_frame("frame_no_bodies", "live", f, "nobody in view: empty bodies array, joints=25")

    big = SkeletonFrame("lab.cam-2:a", 2**40 + 3, 2**62, "azure_kinect",
                        [BodyFrame(2**31 - 1, _pose(rng, 32), np.ones(32))], publish_time_ns=0)
    valid_frame("frame_azure_large_ints", "raw", big,
                "Azure Kinect (32 joints); 64-bit seq and sensor time, body id 2^31-1, t_publish_ns 0 (unknown)")

    # unknown extra keys must be ignored
    m = msgpack.unpackb(good, raw=False)
    m["future_top_level"] = {"anything": [1, 2.5, "x"]}
    m["bodies"][0]["future_body_key"] = b"\x00\x01"
    extra = msgpack.packb(m, use_bin_type=True)
    fr = SkeletonFrame("kinect0", 0, 1_000_000_000, "kinect_v2",
                       [BodyFrame(7, np.frombuffer(m["bodies"][0]["pos"], "<f4").reshape(J, 3),
                                  np.frombuffer(m["bodies"][0]["conf"], "<f4"))], publish_time_ns=T0)
    vectors.append({"name": "frame_unknown_keys", "valid": True, "topic": "sf/raw/kinect0",
                    "description": "frame_raw_one_body plus unknown keys at top level and in the body: ignore them",
                    "payload": extra, "message": _frame_meaning(fr)})

    # --- skeleton messages
    sk = wire.encode_skeleton_message(KINECT_V2, 30.0, "kinect0", publish_time_ns=T0)
    vectors.append({"name": "skeleton_kinect_v2", "valid": True, "topic": "sf/meta/kinect0",
                    "description": "skeleton message for the built-in Kinect v2 layout at 30 Hz",
                    "payload": sk, "message": _skeleton_meaning(KINECT_V2, 30.0, "kinect0", T0)})
    sk = wire.encode_skeleton_message(CUSTOM, 120.0, "arm", publish_time_ns=T0)
    vectors.append({"name": "skeleton_custom", "valid": True, "topic": "sf/meta/arm",
                    "description": "skeleton message announcing a layout that is not built in (4 joints, 3 bones, 120 Hz)",
                    "payload": sk, "message": _skeleton_meaning(CUSTOM, 120.0, "arm", T0)})
    f = SkeletonFrame("arm", 5, 41_666_666, "demo_arm",
                      [BodyFrame(0, _pose(rng, 4), np.array([1.0, 1.0, 0.5, 0.0]))], publish_time_ns=T0)
    f.bodies[0].positions[3] = np.nan
    valid_frame("frame_custom_skeleton", "raw", f,
                "frame of the custom skeleton: decodable only after skeleton_custom", requires="skeleton_custom")

    # optional keys added to version 1 (own generator: the vectors above stay byte for byte)
    f = SkeletonFrame("kinect0", 0, 2_566_666_666, "kinect_v2",
                      [BodyFrame(1, _pose(np.random.default_rng(2026), J), np.ones(J), np.zeros(J, bool))],
                      publish_time_ns=T0 + 5, epoch=1_790_000_000_123_456_789, dropped=4)
    valid_frame("frame_live_epoch_dropped", "live", f,
                "live output in a new epoch (the service restarted this stream's numbering: seq 0 is not "
                "reordering) after shedding 4 input frames under overload (dropped=4)")

    # --- invalid: each must be rejected with the stated reason
    base = msgpack.unpackb(good, raw=False)

    def invalid(name, payload, reason, description, topic="sf/raw/kinect0"):
        vectors.append({"name": name, "valid": False, "reason": reason, "topic": topic,
                        "description": description, "payload": payload})

    def mutated(fn):
        m = msgpack.unpackb(good, raw=False)
        fn(m)
        return msgpack.packb(m, use_bin_type=True)

    invalid("bad_wrong_joint_count",
            mutated(lambda m: m["bodies"][0].update(pos=m["bodies"][0]["pos"][:24 * 12],
                                                   conf=m["bodies"][0]["conf"][:24 * 4])),
            "joints", "kinect_v2 frame whose body carries 24 joints (288-byte pos blob) while 'joints' says 25")
    invalid("bad_joints_field", mutated(lambda m: m.update(joints=24)), "joints",
            "'joints' is 24 but skeleton kinect_v2 has 25")
    invalid("bad_conf_length", mutated(lambda m: m["bodies"][0].update(conf=m["bodies"][0]["conf"][:-4])),
            "joints", "confidence blob 96 bytes instead of 100")
    invalid("bad_rec_length", mutated(lambda m: m["bodies"][0].update(rec=b"\x01" * 3)),
            "joints", "rec blob 3 bytes instead of 25")
    invalid("bad_truncated", good[: len(good) // 2], "truncated",
            "frame_raw_one_body cut in half: ends inside the positions blob")
    invalid("bad_newer_version", mutated(lambda m: m.update(v=2)), "version",
            "otherwise valid frame with protocol version 2: reject, do not guess")
    invalid("bad_garbage", bytes.fromhex("c1deadbeef00ff13"), "garbage",
            "not msgpack (0xc1 is never used)")
    invalid("bad_not_a_map", msgpack.packb([1, "frame", b"x"], use_bin_type=True), "garbage",
            "a msgpack array instead of a map")
    invalid("bad_trailing_bytes", good + b"\x00", "garbage", "a valid frame followed by one extra byte")
    invalid("bad_empty", b"", "garbage", "empty payload")
    invalid("bad_unknown_skeleton", mutated(lambda m: m.update(skeleton="foo")), "skeleton",
            "skeleton 'foo' is neither built in nor announced")
    invalid("bad_missing_seq", mutated(lambda m: m.pop("seq")), "field", "required key 'seq' missing")
    invalid("bad_seq_type", mutated(lambda m: m.update(seq="7")), "field", "'seq' is a string")
    invalid("bad_negative_seq", mutated(lambda m: m.update(seq=-1)), "field", "'seq' is negative")
    invalid("bad_epoch_type", mutated(lambda m: m.update(epoch="1")), "field",
            "optional 'epoch' present but a string, not an unsigned integer")
    invalid("bad_time_range", mutated(lambda m: m.update(t_sensor_ns=2**63)), "field",
            "t_sensor_ns 2^63 (a uint64) does not fit the signed 64-bit range of times")
    invalid("bad_pos_not_bin", mutated(lambda m: m["bodies"][0].update(pos=[0.0] * 75)), "field",
            "positions sent as an array of floats instead of a float32 blob")
    invalid("bad_duplicate_body",
            mutated(lambda m: m["bodies"].append(dict(m["bodies"][0]))), "field",
            "two bodies with the same id 7")
    invalid("bad_unknown_type", mutated(lambda m: m.update(type="hello")), "type",
            "unknown message type: skip it (count as ignored, not malformed)")
    invalid("bad_skeleton_bone", msgpack.packb({
        "v": 1, "type": "skeleton", "stream": "arm", "skeleton": "broken", "joint_names": ["a", "b"],
        "bones": [[0, 2]], "rate_hz": 30.0, "units": "m", "t_publish_ns": T0}, use_bin_type=True),
        "field", "skeleton message whose bone [0, 2] names a joint that does not exist", topic="sf/meta/arm")
    invalid("bad_skeleton_version", msgpack.packb({
        "v": 3, "type": "skeleton", "stream": "arm", "skeleton": "demo_arm",
        "joint_names": list(CUSTOM.joint_names), "bones": [list(b) for b in CUSTOM.bones],
        "rate_hz": 120.0, "units": "m", "t_publish_ns": T0}, use_bin_type=True),
        "version", "skeleton message from protocol version 3", topic="sf/meta/arm")
    return vectors


def _check(vectors: list[dict]) -> None:
    """Refuse to write a vector the wire module does not treat as stated."""
    known: dict[str, Skeleton] = {}
    for v in vectors:
        try:
            msg = wire.decode_message(v["payload"], known)
        except wire.WireError as exc:
            if v["valid"]:
                raise SystemExit(f"{v['name']}: valid vector rejected: {exc}")
            if exc.reason != v["reason"]:
                raise SystemExit(f"{v['name']}: rejected for {exc.reason!r} ({exc}), expected {v['reason']!r}")
            v["error"] = str(exc)
            continue
        if not v["valid"]:
            raise SystemExit(f"{v['name']}: invalid vector accepted by streamfix.transport.wire")
        if isinstance(msg, wire.SkeletonMessage):
            known[msg.skeleton.name] = msg.skeleton


def write_vectors(out: Path) -> list[str]:
    vectors = build_vectors()
    _check(vectors)
    out.mkdir(parents=True, exist_ok=True)
    names = []
    for v in vectors:
        payload = v.pop("payload")
        (out / f"{v['name']}.bin").write_bytes(payload)
        meta = {"name": v["name"], "valid": v["valid"], "description": v["description"], "topic": v["topic"]}
        for key in ("requires", "reason", "error", "message"):
            if key in v:
                meta[key] = v[key]
        meta["size"] = len(payload)
        (out / f"{v['name']}.json").write_text(json.dumps(meta, indent=1, allow_nan=False) + "\n")
        names.append(v["name"])
    index = {"protocol_version": wire.PROTOCOL_VERSION, "vectors": names}
    (out / "index.json").write_text(json.dumps(index, indent=1) + "\n")
    return names


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE / "vectors")
    args = parser.parse_args(argv)
    names = write_vectors(args.out)
    print(f"wrote {len(names)} vectors to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
