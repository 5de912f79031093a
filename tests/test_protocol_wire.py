"""Wire format: round trips, missing joints, strict rejection with clear messages, topics."""
from __future__ import annotations

import json
from pathlib import Path

import msgpack
import numpy as np
import pytest

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.skeletons import AZURE_KINECT, KINECT_V2, MEDIAPIPE_POSE, Skeleton
from streamfix.transport import wire
from streamfix.transport.wire import WireError

VECTORS = Path(__file__).resolve().parents[1] / "protocol" / "vectors"


def _random_frame(rng: np.random.Generator, skeleton: Skeleton, n_bodies: int, recovered: bool) -> SkeletonFrame:
    J = skeleton.n_joints
    bodies = []
    for k in range(n_bodies):
        pos = rng.normal(0, 1, size=(J, 3))
        conf = rng.choice([0.0, 0.5, 1.0], size=J)
        pos[conf == 0] = np.nan
        rec = rng.random(J) < 0.2 if recovered else None
        bodies.append(BodyFrame(int(rng.integers(0, 2**31)) * 8 + k, pos, conf, rec))
    return SkeletonFrame(
        stream_id="cam-1", seq=int(rng.integers(0, 2**60)), sensor_time_ns=int(rng.integers(-2**62, 2**62)),
        skeleton=skeleton.name, bodies=bodies, publish_time_ns=int(rng.integers(0, 2**62)),
        filled=bool(rng.random() < 0.5),
    )


@pytest.mark.parametrize("skeleton", [KINECT_V2, AZURE_KINECT, MEDIAPIPE_POSE], ids=lambda s: s.name)
@pytest.mark.parametrize("n_bodies", [0, 1, 6])
@pytest.mark.parametrize("recovered", [False, True])
def test_round_trip_keeps_everything_to_float32(skeleton, n_bodies, recovered):
    rng = np.random.default_rng(n_bodies * 7 + recovered)
    frame = _random_frame(rng, skeleton, n_bodies, recovered)
    got = wire.decode_frame(wire.encode_frame(frame))
    for attr in ("stream_id", "seq", "sensor_time_ns", "publish_time_ns", "skeleton", "filled"):
        assert getattr(got, attr) == getattr(frame, attr), attr
    assert [b.body_id for b in got.bodies] == [b.body_id for b in frame.bodies]
    for g, b in zip(got.bodies, frame.bodies):
        assert g.positions.shape == (skeleton.n_joints, 3) and g.positions.dtype == np.float64
        np.testing.assert_array_equal(np.isnan(g.positions), np.isnan(b.positions))
        # float32 on the wire: relative error below 2^-24
        ok = ~np.isnan(b.positions)
        assert np.all(np.abs(g.positions[ok] - b.positions[ok]) <= 6e-8 * np.abs(b.positions[ok]))
        np.testing.assert_array_equal(g.confidence, b.confidence)
        if recovered:
            np.testing.assert_array_equal(g.recovered, b.recovered)
        else:
            assert g.recovered is None


def test_nan_and_inf_coordinates_are_missing_joints_not_errors():
    J = KINECT_V2.n_joints
    pos = np.ones((J, 3))
    pos[2, 1] = np.nan
    pos[5, 0] = np.inf
    pos[9, 2] = -np.inf
    frame = SkeletonFrame("s", 0, 0, "kinect_v2", [BodyFrame(3, pos, np.ones(J))])
    got = wire.decode_frame(wire.encode_frame(frame)).bodies[0]
    missing = [2, 5, 9]
    assert np.isnan(got.positions[missing]).all()
    assert (got.confidence[missing] == 0).all()
    others = np.setdiff1d(np.arange(J), missing)
    assert np.isfinite(got.positions[others]).all() and (got.confidence[others] == 1).all()


def test_nan_confidence_reads_as_missing_and_out_of_range_is_clipped():
    J = KINECT_V2.n_joints
    conf = np.ones(J)
    conf[0], conf[1], conf[2] = np.nan, 1.5, -0.2
    frame = SkeletonFrame("s", 0, 0, "kinect_v2", [BodyFrame(1, np.zeros((J, 3)), conf)])
    got = wire.decode_frame(wire.encode_frame(frame)).bodies[0].confidence
    assert got[0] == 0.0 and got[1] == 1.0 and got[2] == 0.0


def _load_vectors():
    index = json.loads((VECTORS / "index.json").read_text())
    return [(json.loads((VECTORS / f"{n}.json").read_text()), (VECTORS / f"{n}.bin").read_bytes())
            for n in index["vectors"]]


def _meaning(msg) -> dict:
    """The vector-file form of a decoded message."""
    if isinstance(msg, wire.SkeletonMessage):
        return {"type": "skeleton", "stream": msg.stream_id, "skeleton": msg.skeleton.name,
                "joint_names": list(msg.skeleton.joint_names), "bones": [list(b) for b in msg.skeleton.bones],
                "rate_hz": msg.rate_hz, "units": msg.units, "t_publish_ns": msg.publish_time_ns}
    return {
        "type": "frame", "stream": msg.stream_id, "seq": msg.seq, "t_sensor_ns": msg.sensor_time_ns,
        "t_publish_ns": msg.publish_time_ns, "skeleton": msg.skeleton,
        "joints": len(msg.bodies[0].confidence) if msg.bodies else None,  # J only shows through bodies
        "filled": msg.filled,
        "bodies": [{
            "id": b.body_id,
            "positions": [None if np.isnan(p).any() else p.tolist() for p in b.positions],
            "confidence": b.confidence.tolist(),
            "recovered": None if b.recovered is None else b.recovered.tolist(),
        } for b in msg.bodies],
        **({"epoch": msg.epoch} if msg.epoch else {}),  # optional keys, stated only when present
        **({"dropped": msg.dropped} if msg.dropped else {}),
    }


def test_every_valid_vector_decodes_to_its_stated_meaning():
    known: dict[str, Skeleton] = {}
    checked = 0
    for meta, payload in _load_vectors():
        if not meta["valid"]:
            continue
        msg = wire.decode_message(payload, known)
        if isinstance(msg, wire.SkeletonMessage):
            known[msg.skeleton.name] = msg.skeleton
        got = _meaning(msg)
        want = dict(meta["message"])
        if want["type"] == "frame" and not want["bodies"]:
            want["joints"] = None  # J is not observable without bodies
        assert got == want, meta["name"]
        checked += 1
    assert checked >= 8


def test_every_invalid_vector_is_rejected_with_its_reason():
    known = {}
    reasons = set()
    for meta, payload in _load_vectors():
        if meta["valid"]:
            msg = wire.decode_message(payload, known)
            if isinstance(msg, wire.SkeletonMessage):
                known[msg.skeleton.name] = msg.skeleton
            continue
        with pytest.raises(WireError) as info:
            wire.decode_message(payload, known)
        assert info.value.reason == meta["reason"], (meta["name"], str(info.value))
        assert isinstance(info.value, ValueError)
        reasons.add(meta["reason"])
    # the list of bad input: garbage, truncated, wrong joint count, unknown skeleton, newer version
    assert {"garbage", "truncated", "joints", "skeleton", "version", "field", "type"} <= reasons


def test_custom_skeleton_decodes_only_once_announced():
    arm = Skeleton("test_arm_only_here", ("a", "b", "c"), ((0, 1), (1, 2)))
    meta = wire.decode_skeleton_message(wire.encode_skeleton_message(arm, 60.0, "arm"))
    assert meta.skeleton == arm and meta.rate_hz == 60.0 and meta.stream_id == "arm"
    frame = SkeletonFrame("arm", 1, 5, arm.name, [BodyFrame(0, np.zeros((3, 3)), np.ones(3))])
    payload = wire.encode_frame(frame)
    with pytest.raises(WireError, match="unknown skeleton 'test_arm_only_here'") as info:
        wire.decode_frame(payload)
    assert info.value.reason == "skeleton"
    assert wire.decode_frame(payload, {arm.name: arm}).bodies[0].positions.shape == (3, 3)


def _good_payload() -> bytes:
    J = KINECT_V2.n_joints
    return wire.encode_frame(SkeletonFrame("k", 1, 2, "kinect_v2", [BodyFrame(3, np.zeros((J, 3)), np.ones(J))]))


def test_error_messages_say_what_was_expected_and_what_arrived():
    m = msgpack.unpackb(_good_payload(), raw=False)
    m["bodies"][0]["pos"] = m["bodies"][0]["pos"][:96]
    with pytest.raises(WireError) as info:
        wire.decode_frame(msgpack.packb(m, use_bin_type=True))
    assert str(info.value) == "body 3: positions blob has 96 bytes, expected 300 (25 joints x 3 x float32)"

    m = msgpack.unpackb(_good_payload(), raw=False)
    m["v"] = 2
    with pytest.raises(WireError, match=r"^protocol version 2 is newer than supported 1$"):
        wire.decode_frame(msgpack.packb(m, use_bin_type=True))

    m = msgpack.unpackb(_good_payload(), raw=False)
    m["skeleton"] = "foo"
    with pytest.raises(WireError, match=r"unknown skeleton 'foo'"):
        wire.decode_frame(msgpack.packb(m, use_bin_type=True))

    with pytest.raises(WireError, match="truncated"):
        wire.decode_frame(_good_payload()[:-10])


def test_encoder_refuses_inconsistent_bodies():
    J = KINECT_V2.n_joints
    a = BodyFrame(1, np.zeros((J, 3)), np.ones(J))
    b = BodyFrame(2, np.zeros((J - 1, 3)), np.ones(J - 1))
    with pytest.raises(WireError, match="body 2: has 24 joints, other bodies in the frame have 25"):
        wire.encode_frame(SkeletonFrame("k", 0, 0, "kinect_v2", [a, b]))
    with pytest.raises(WireError, match=r"confidence shape \(3,\), expected \(25,\)"):
        wire.encode_frame(SkeletonFrame("k", 0, 0, "kinect_v2", [BodyFrame(1, np.zeros((J, 3)), np.ones(3))]))


def test_random_corruption_only_ever_raises_wire_error():
    """Bit flips and cuts of a valid payload: decoded or WireError, never anything else."""
    rng = np.random.default_rng(5)
    good = bytearray(_good_payload())
    outcomes = {"ok": 0, "rejected": 0}
    for _ in range(1500):
        data = bytearray(good)
        for _ in range(int(rng.integers(1, 4))):
            data[int(rng.integers(len(data)))] = int(rng.integers(256))
        if rng.random() < 0.3:
            data = data[: int(rng.integers(len(data)))]
        try:
            frame = wire.decode_frame(bytes(data))
        except WireError:
            outcomes["rejected"] += 1
            continue
        outcomes["ok"] += 1
        for b in frame.bodies:  # whatever got through obeys the conventions
            assert b.positions.shape == (KINECT_V2.n_joints, 3)
            assert np.all((b.confidence >= 0) & (b.confidence <= 1))
            assert np.all(np.isfinite(b.positions) | (b.confidence[:, None] == 0))
    assert outcomes["ok"] > 0 and outcomes["rejected"] > 0


def test_topics():
    assert wire.topic_for("live", "kinect0") == b"sf/live/kinect0"
    for kind in wire.KINDS:
        assert wire.parse_topic(wire.topic_for(kind, "a.b:c-1_2")) == (kind, "a.b:c-1_2")
        assert wire.topic_for(kind, "x").startswith(wire.topic_prefix(kind))
    for bad in (b"sf/live/", b"sf/other/x", b"live/x", b"sf/live/a/b", b"\xff"):
        with pytest.raises(WireError):
            wire.parse_topic(bad)
    with pytest.raises(WireError):
        wire.topic_for("live", "has/slash")
    with pytest.raises(ValueError):
        wire.topic_for("nope", "x")
    assert wire.resolve_topic_arg("clean") == b"sf/clean/"
    assert wire.resolve_topic_arg("live/kinect0") == b"sf/live/kinect0"
    assert wire.resolve_topic_arg("sf/") == b"sf/"


def test_encoder_names_unencodable_fields():
    with pytest.raises(WireError, match="stream id 'a/b'"):
        wire.encode_frame(SkeletonFrame("a/b", 0, 0, "kinect_v2", []))
    with pytest.raises(WireError, match="does not fit an unsigned 64-bit integer"):
        wire.encode_frame(SkeletonFrame("a", 2**64, 0, "kinect_v2", []))
    with pytest.raises(WireError, match="t_sensor_ns 1180591620717411303424 does not fit a signed 64-bit"):
        wire.encode_frame(SkeletonFrame("a", 1, 2**70, "kinect_v2", []))
    J = KINECT_V2.n_joints
    with pytest.raises(WireError, match="cannot encode frame of stream 'a' seq 1"):
        wire.encode_frame(SkeletonFrame("a", 1, 0, "kinect_v2", [BodyFrame(2**70, np.zeros((J, 3)), np.ones(J))]))
