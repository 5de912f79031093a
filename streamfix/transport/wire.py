"""The streamfix wire format: msgpack messages on ZeroMQ topics (``protocol/SPEC.md``).

Every ZeroMQ message is two frames, ``[topic, payload]``. The topic is
``sf/<kind>/<stream>`` with kind one of ``raw`` (sensor input), ``live`` (low-latency
cleaned output), ``clean`` (refined cleaned output) or ``meta`` (skeleton message).
The payload is one msgpack map using only maps, arrays, integers, floats, strings,
booleans and binary blobs (no extension types), so MessagePack-CSharp, msgpack-c and
Python decode it without custom code. Joint arrays are blobs of little-endian float32.

Frame message (``type == "frame"``)::

    {"v": 1, "type": "frame", "stream": str, "seq": uint, "t_sensor_ns": int,
     "t_publish_ns": int, "skeleton": str, "joints": J, "filled": bool,
     "bodies": [{"id": int, "pos": bin(J*3*4), "conf": bin(J*4), "rec": bin(J)?}, ...],
     "epoch": uint?, "dropped": uint?}

``epoch`` (service output) names the run of ``seq`` numbering the frame belongs to and
``dropped`` counts input frames shed under overload just before it; both are optional
additions to version 1, written only when non-zero.

Skeleton message (``type == "skeleton"``, topic ``sf/meta/<stream>``)::

    {"v": 1, "type": "skeleton", "stream": str, "skeleton": str, "joint_names": [str],
     "bones": [[parent, child], ...], "rate_hz": float, "units": "m", "t_publish_ns": int}

Decoding is strict about what it needs and lenient about what it does not: a newer
major version, a wrong blob length, an unknown skeleton or a truncated payload raise
:class:`WireError` (the caller counts and skips the message); unknown extra keys are
ignored; NaN/inf coordinates are missing joints (NaN position, confidence 0).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable, Mapping, Optional, Union

import msgpack
import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..skeletons import Skeleton, get_skeleton

__all__ = [
    "PROTOCOL_VERSION",
    "KINDS",
    "TOPIC_ROOT",
    "WireError",
    "SkeletonMessage",
    "encode_frame",
    "decode_frame",
    "encode_skeleton_message",
    "decode_skeleton_message",
    "decode_message",
    "message_type",
    "topic_for",
    "topic_prefix",
    "parse_topic",
    "resolve_topic_arg",
    "check_stream_id",
]

PROTOCOL_VERSION = 1
"""Major protocol version this module writes and the newest it reads."""

TOPIC_ROOT = b"sf/"
KINDS = ("raw", "live", "clean", "meta")
"""Topic kinds: sensor input, low-latency output, refined output, skeleton messages."""

SkeletonTables = Optional[Union[Mapping[str, Skeleton], Callable[[str], Mapping[str, Skeleton]]]]
"""Where a decoder looks up announced skeletons: one map, or one map per stream id."""

_STREAM_RE = re.compile(r"^[A-Za-z0-9_.:\-]{1,64}$")
_F32 = np.dtype("<f4")
_MAX_JOINTS = 1024
_MAX_BODIES = 64
_MAX_MAP_LEN = 256       # keys in any map (a frame has 10, a body 4; room for unknown keys)
_MAX_ARRAY_LEN = 4 * _MAX_JOINTS  # joint names, bones (a skeleton of 1024 joints), bodies


def _head_type(head: int) -> str:
    """What a msgpack value starting with byte ``head`` is (for error messages)."""
    if head <= 0x7F or head >= 0xE0 or 0xCC <= head <= 0xD3:
        return "an integer"
    if 0x90 <= head <= 0x9F or head in (0xDC, 0xDD):
        return "an array"
    if 0xA0 <= head <= 0xBF or 0xD9 <= head <= 0xDB:
        return "a string"
    names = {0xC0: "nil", 0xC2: "a boolean", 0xC3: "a boolean", 0xC4: "a binary blob", 0xC5: "a binary blob",
             0xC6: "a binary blob", 0xCA: "a float", 0xCB: "a float"}
    return names.get(head, "no valid msgpack value" if head == 0xC1 else "an extension type (not allowed)")


class WireError(ValueError):
    """A message that cannot be decoded; ``reason`` is a short counter key.

    Reasons: ``garbage`` (not msgpack / not a map), ``truncated``, ``version``
    (newer major version), ``type`` (unknown or unexpected message type; a subscriber
    ignores unknown types), ``skeleton`` (unknown skeleton), ``joints`` (joint count or
    blob length does not match), ``field`` (a required field is missing or mistyped).
    """

    def __init__(self, message: str, reason: str = "field") -> None:
        super().__init__(message)
        self.reason = reason


@dataclass
class SkeletonMessage:
    """Decoded skeleton/metadata message: what a subscriber needs to decode frames."""

    stream_id: str
    skeleton: Skeleton
    rate_hz: float
    units: str = "m"
    publish_time_ns: int = 0


# --------------------------------------------------------------------------- topics

def check_stream_id(stream_id: str) -> str:
    """Return ``stream_id`` if it is 1-64 chars of ``[A-Za-z0-9_.:-]``, else WireError."""
    if not isinstance(stream_id, str) or not _STREAM_RE.match(stream_id):
        raise WireError(
            f"stream id {stream_id!r} is not 1-64 characters of letters, digits, '_', '.', ':', '-'",
            "field",
        )
    return stream_id


def topic_prefix(kind: str) -> bytes:
    """ZeroMQ subscription prefix for every stream of one kind, e.g. ``b"sf/live/"``."""
    if kind not in KINDS:
        raise ValueError(f"unknown topic kind {kind!r}; expected one of {', '.join(KINDS)}")
    return TOPIC_ROOT + kind.encode() + b"/"


def topic_for(kind: str, stream_id: str) -> bytes:
    """Topic of one stream, e.g. ``topic_for("live", "kinect0") == b"sf/live/kinect0"``."""
    return topic_prefix(kind) + check_stream_id(stream_id).encode()


def parse_topic(topic: bytes) -> tuple[str, str]:
    """``b"sf/live/kinect0"`` -> ``("live", "kinect0")``; WireError if not a streamfix topic."""
    try:
        text = bytes(topic).decode("ascii")
    except (UnicodeDecodeError, TypeError):
        raise WireError(f"topic {topic!r} is not ASCII", "field") from None
    parts = text.split("/")
    if len(parts) != 3 or parts[0] != "sf" or parts[1] not in KINDS or not _STREAM_RE.match(parts[2]):
        raise WireError(f"topic {text!r} is not sf/<raw|live|clean|meta>/<stream>", "field")
    return parts[1], parts[2]


def resolve_topic_arg(arg: str) -> bytes:
    """A command-line ``--topic``: a kind (``live``), ``kind/stream``, or a raw prefix."""
    if arg in KINDS:
        return topic_prefix(arg)
    head, sep, rest = arg.partition("/")
    if sep and head in KINDS:
        return topic_prefix(head) + rest.encode()
    return arg.encode()


# --------------------------------------------------------------------------- encode

def _now_ns() -> int:
    import time

    return time.time_ns()


def encode_frame(frame: SkeletonFrame, *, publish_time_ns: int | None = None) -> bytes:
    """Encode one frame as a msgpack ``frame`` message.

    ``publish_time_ns`` overrides ``frame.publish_time_ns`` (pass ``time.time_ns()``
    when publishing). Positions go out as float32 metres, NaN for missing joints.
    """
    bodies = frame.bodies
    n_joints = -1
    out_bodies = []
    for b in bodies:
        pos = np.asarray(b.positions)
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise WireError(f"body {b.body_id}: positions must be (J, 3), got {pos.shape}", "joints")
        if n_joints < 0:
            n_joints = pos.shape[0]
        elif pos.shape[0] != n_joints:
            raise WireError(
                f"body {b.body_id}: has {pos.shape[0]} joints, other bodies in the frame have {n_joints}",
                "joints",
            )
        conf = np.asarray(b.confidence)
        if conf.shape != (n_joints,):
            raise WireError(
                f"body {b.body_id}: confidence shape {conf.shape}, expected ({n_joints},)", "joints"
            )
        body = {
            "id": int(b.body_id),
            "pos": pos.astype(_F32, copy=False).tobytes(),
            "conf": conf.astype(_F32, copy=False).tobytes(),
        }
        if b.recovered is not None:
            rec = np.asarray(b.recovered)
            if rec.shape != (n_joints,):
                raise WireError(
                    f"body {b.body_id}: recovered shape {rec.shape}, expected ({n_joints},)", "joints"
                )
            body["rec"] = rec.astype(np.uint8, copy=False).tobytes()
        out_bodies.append(body)
    if n_joints < 0:
        try:
            n_joints = get_skeleton(frame.skeleton).n_joints
        except KeyError:
            n_joints = 0
    msg = {
        "v": PROTOCOL_VERSION,
        "type": "frame",
        "stream": check_stream_id(frame.stream_id),
        "seq": int(frame.seq),
        "t_sensor_ns": int(frame.sensor_time_ns),
        "t_publish_ns": int(frame.publish_time_ns if publish_time_ns is None else publish_time_ns),
        "skeleton": frame.skeleton,
        "joints": n_joints,
        "filled": bool(frame.filled),
        "bodies": out_bodies,
    }
    for key in ("epoch", "dropped"):  # optional (SPEC 4.1): absent when 0
        value = int(getattr(frame, key, 0) or 0)
        if value:
            msg[key] = value
    for key in ("seq", "epoch", "dropped"):
        if not 0 <= msg.get(key, 0) < _U64_LIMIT:
            raise WireError(f"{key} {msg[key]} does not fit an unsigned 64-bit integer", "field")
    for key in ("t_sensor_ns", "t_publish_ns"):
        if not _I64_MIN <= msg[key] <= _I64_MAX:
            raise WireError(f"{key} {msg[key]} does not fit a signed 64-bit integer", "field")
    try:
        return msgpack.packb(msg, use_bin_type=True)
    except (OverflowError, TypeError, ValueError) as exc:
        raise WireError(f"cannot encode frame of stream {frame.stream_id!r} seq {frame.seq}: {exc}", "field") from None


def encode_skeleton_message(
    skeleton: Skeleton,
    rate_hz: float,
    stream_id: str,
    *,
    publish_time_ns: int | None = None,
    units: str = "m",
) -> bytes:
    """Encode the skeleton/metadata message of one stream (topic ``sf/meta/<stream>``)."""
    msg = {
        "v": PROTOCOL_VERSION,
        "type": "skeleton",
        "stream": check_stream_id(stream_id),
        "skeleton": skeleton.name,
        "joint_names": list(skeleton.joint_names),
        "bones": [[int(a), int(b)] for a, b in skeleton.bones],
        "rate_hz": float(rate_hz),
        "units": units,
        "t_publish_ns": int(_now_ns() if publish_time_ns is None else publish_time_ns),
    }
    return msgpack.packb(msg, use_bin_type=True)


# --------------------------------------------------------------------------- decode

def _unpack(payload: bytes) -> dict:
    if not payload:
        raise WireError("payload is empty, expected a msgpack map", "garbage")
    head = payload[0]
    if not (0x80 <= head <= 0x8F or head in (0xDE, 0xDF)):  # decide before decoding a possible bomb
        raise WireError(f"payload is not a msgpack map: its first byte 0x{head:02x} starts {_head_type(head)}",
                        "garbage")
    try:
        # bounded containers: no valid message needs more, and a bomb fails at its first header
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=False, max_map_len=_MAX_MAP_LEN,
                              max_array_len=_MAX_ARRAY_LEN)
    except msgpack.ExtraData as exc:
        raise WireError(
            f"payload of {len(payload)} bytes is not one msgpack map: a msgpack "
            f"{_mp_type(exc.unpacked)} followed by {len(exc.extra)} trailing bytes",
            "garbage",
        ) from None
    except (ValueError, msgpack.UnpackException, TypeError) as exc:
        text = str(exc) or type(exc).__name__
        if "incomplete" in text.lower() or "insufficient" in text.lower():
            raise WireError(f"payload truncated: {len(payload)} bytes end inside a msgpack value", "truncated") from None
        raise WireError(f"payload of {len(payload)} bytes is not valid msgpack ({text})", "garbage") from None
    except Exception as exc:  # msgpack may raise FormatError/StackError subclasses
        text = str(exc) or type(exc).__name__
        raise WireError(f"payload of {len(payload)} bytes is not valid msgpack ({text})", "garbage") from None
    if not isinstance(msg, dict):
        raise WireError(f"payload is a msgpack {_mp_type(msg)}, expected a map", "garbage")
    v = msg.get("v")
    if not isinstance(v, int) or isinstance(v, bool):
        raise WireError(f"field 'v' (protocol version) is missing or not an integer: {v!r}", "field")
    if v > PROTOCOL_VERSION:
        raise WireError(f"protocol version {v} is newer than supported {PROTOCOL_VERSION}", "version")
    if v < 1:
        raise WireError(f"protocol version {v} is not a valid version (versions start at 1)", "version")
    return msg


def _field(msg: dict, key: str, types, what: str):
    value = msg.get(key)
    if not isinstance(value, types) or (isinstance(value, bool) and bool not in _tuple(types)):
        if key not in msg:
            raise WireError(f"field {key!r} ({what}) is missing", "field")
        raise WireError(f"field {key!r} is a msgpack {_mp_type(value)} ({value!r:.40}), expected {what}", "field")
    return value


_I64_MIN, _I64_MAX = -(2**63), 2**63 - 1
_U64_LIMIT = 2**64


def _uint64_opt(msg: dict, key: str) -> int:
    """An optional unsigned 64-bit integer field (0 when absent)."""
    if key not in msg:
        return 0
    value = _field(msg, key, int, "a non-negative integer")
    if not 0 <= value < _U64_LIMIT:
        raise WireError(f"field {key!r} is {value}, outside the unsigned 64-bit range", "field")
    return value


def _int64(msg: dict, key: str) -> int:
    """A required signed 64-bit integer field (times in ns)."""
    value = _field(msg, key, int, "an integer (ns)")
    if not _I64_MIN <= value <= _I64_MAX:
        raise WireError(f"field {key!r} is {value}, outside the signed 64-bit range", "field")
    return value


def _mp_type(value) -> str:
    """The msgpack family of a decoded value, for error messages."""
    for t, name in ((bool, "boolean"), (int, "integer"), (float, "float"), (str, "string"),
                    (bytes, "binary"), (list, "array"), (dict, "map"), (type(None), "nil")):
        if isinstance(value, t):
            return name
    return type(value).__name__


def _tuple(types) -> tuple:
    return types if isinstance(types, tuple) else (types,)


def message_type(payload: bytes) -> str:
    """The ``type`` of a message after version checks (``"frame"``, ``"skeleton"``, ...)."""
    return _field(_unpack(payload), "type", str, "a string")


def _lookup_skeleton(name: str, skeletons: Mapping[str, Skeleton] | None) -> Skeleton:
    if skeletons is not None:
        found = skeletons.get(name)
        if found is not None:
            return found
    try:
        return get_skeleton(name)
    except KeyError:
        raise WireError(
            f"unknown skeleton {name!r} (not in the registry and no skeleton message seen for it)",
            "skeleton",
        ) from None


def _blob(body: dict, key: str, bid: int, n_bytes: int, what: str) -> bytes:
    value = body.get(key)
    if isinstance(value, bytes):
        return value
    if key not in body:
        raise WireError(f"body {bid}: field {key!r} is missing", "field")
    raise WireError(
        f"body {bid}: field {key!r} is a msgpack {_mp_type(value)}, expected a binary blob of "
        f"{n_bytes} bytes ({what})",
        "field",
    )


def _stream_of(msg: dict, expected_type: str) -> str:
    """Check the message type and return its valid stream id."""
    mtype = _field(msg, "type", str, "a string")
    if mtype != expected_type:
        raise WireError(f"expected message type {expected_type!r}, got {mtype!r}", "type")
    stream = _field(msg, "stream", str, "a string")
    if not _STREAM_RE.match(stream):
        raise WireError(f"stream id {stream!r} is not 1-64 characters of [A-Za-z0-9_.:-]", "field")
    return stream


def _frame_from_map(msg: dict, skeletons: "SkeletonTables") -> SkeletonFrame:
    stream = _stream_of(msg, "frame")
    seq = _field(msg, "seq", int, "a non-negative integer")
    if seq < 0:
        raise WireError(f"field 'seq' is {seq}, expected a non-negative integer", "field")
    epoch, dropped = _uint64_opt(msg, "epoch"), _uint64_opt(msg, "dropped")
    t_sensor = _int64(msg, "t_sensor_ns")
    t_pub = _int64(msg, "t_publish_ns")
    name = _field(msg, "skeleton", str, "a string")
    n_joints = _field(msg, "joints", int, "a non-negative integer")
    filled = _field(msg, "filled", bool, "a boolean")
    bodies_raw = _field(msg, "bodies", list, "an array")
    if callable(skeletons):  # per-stream tables (the service scopes announcements to their stream)
        skeletons = skeletons(stream)
    skeleton = _lookup_skeleton(name, skeletons)
    if bodies_raw and n_joints != skeleton.n_joints:
        raise WireError(
            f"frame declares {n_joints} joints but skeleton {name!r} has {skeleton.n_joints}", "joints"
        )
    if len(bodies_raw) > _MAX_BODIES:
        raise WireError(f"frame has {len(bodies_raw)} bodies, more than the limit {_MAX_BODIES}", "field")
    J = skeleton.n_joints
    bodies: list[BodyFrame] = []
    seen: set[int] = set()
    for i, b in enumerate(bodies_raw):
        if not isinstance(b, dict):
            raise WireError(f"body {i}: is a msgpack {_mp_type(b)}, expected a map", "field")
        bid = b.get("id")
        if not isinstance(bid, int) or isinstance(bid, bool):
            raise WireError(f"body {i}: field 'id' is missing or not an integer: {bid!r:.40}", "field")
        if not _I64_MIN <= bid <= _I64_MAX:
            raise WireError(f"body {i}: id {bid} does not fit a signed 64-bit integer", "field")
        if bid in seen:
            raise WireError(f"body {i}: duplicate body id {bid}", "field")
        seen.add(bid)
        pos_b = _blob(b, "pos", bid, J * 12, "float32 LE positions")
        if len(pos_b) != J * 12:
            raise WireError(
                f"body {bid}: positions blob has {len(pos_b)} bytes, expected {J * 12} "
                f"({J} joints x 3 x float32)",
                "joints",
            )
        conf_b = _blob(b, "conf", bid, J * 4, "float32 LE confidence")
        if len(conf_b) != J * 4:
            raise WireError(
                f"body {bid}: confidence blob has {len(conf_b)} bytes, expected {J * 4} "
                f"({J} joints x float32)",
                "joints",
            )
        positions = np.frombuffer(pos_b, dtype=_F32).astype(np.float64).reshape(J, 3)
        confidence = np.frombuffer(conf_b, dtype=_F32).astype(np.float64)
        if not ((confidence >= 0.0) & (confidence <= 1.0)).all():  # NaN fails both tests
            # NaN confidence means unknown -> missing; clip the rest into [0, 1].
            confidence = np.where(confidence > 1.0, 1.0, np.where(confidence >= 0.0, confidence, 0.0))
        finite = np.isfinite(positions)
        if not finite.all():  # a non-finite coordinate makes the joint missing
            bad = ~finite.all(axis=1)
            positions[bad] = np.nan
            confidence[bad] = 0.0
        recovered = None
        rec_b = b.get("rec")
        if rec_b is not None:
            rec_b = _blob(b, "rec", bid, J, "uint8 recovered flags")
            if len(rec_b) != J:
                raise WireError(
                    f"body {bid}: recovered blob has {len(rec_b)} bytes, expected {J} ({J} joints x uint8)",
                    "joints",
                )
            recovered = np.frombuffer(rec_b, dtype=np.uint8) != 0
        bodies.append(BodyFrame(bid, positions, confidence, recovered))
    return SkeletonFrame(
        stream_id=stream,
        seq=seq,
        sensor_time_ns=t_sensor,
        skeleton=name,
        bodies=bodies,
        publish_time_ns=t_pub,
        filled=filled,
        epoch=epoch,
        dropped=dropped,
    )


def decode_frame(payload: bytes, skeletons: "SkeletonTables" = None) -> SkeletonFrame:
    """Decode a ``frame`` message; raises :class:`WireError` saying what is wrong.

    ``skeletons`` maps skeleton names to layouts learned from skeleton messages, or is
    a function of the frame's stream id returning such a map (layouts scoped to the
    stream that announced them); names not in it are looked up in the registry
    (``streamfix.skeletons``).
    """
    return _frame_from_map(_unpack(payload), skeletons)


def _skeleton_from_map(msg: dict) -> SkeletonMessage:
    stream = _stream_of(msg, "skeleton")
    name = _field(msg, "skeleton", str, "a string")
    names = _field(msg, "joint_names", list, "an array of strings")
    if not all(isinstance(n, str) for n in names):
        raise WireError("field 'joint_names' holds a non-string", "field")
    if len(names) > _MAX_JOINTS:
        raise WireError(f"skeleton has {len(names)} joints, more than the limit {_MAX_JOINTS}", "joints")
    bones = _field(msg, "bones", list, "an array of [parent, child] pairs")
    for bone in bones:
        if not (isinstance(bone, list) and len(bone) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in bone)):
            raise WireError(f"bone {bone!r:.40} is not a [parent, child] pair of integers", "field")
    rate = _field(msg, "rate_hz", (int, float), "a number (Hz)")
    if not (np.isfinite(rate) and rate > 0):
        raise WireError(f"field 'rate_hz' is {rate}, expected a positive number", "field")
    units = msg.get("units", "m")
    if units != "m":
        raise WireError(f"field 'units' is {units!r}, expected 'm'", "field")
    t_pub = _int64(msg, "t_publish_ns") if "t_publish_ns" in msg else 0
    try:
        skeleton = Skeleton(name, tuple(names), tuple(tuple(b) for b in bones))
    except ValueError as exc:
        raise WireError(str(exc), "field") from None
    return SkeletonMessage(stream, skeleton, float(rate), units, t_pub)


def decode_skeleton_message(payload: bytes) -> SkeletonMessage:
    """Decode a ``skeleton`` message into a :class:`SkeletonMessage`."""
    return _skeleton_from_map(_unpack(payload))


def decode_message(
    payload: bytes, skeletons: "SkeletonTables" = None
) -> Union[SkeletonFrame, SkeletonMessage]:
    """Decode any message: a :class:`SkeletonFrame` or a :class:`SkeletonMessage`.

    An unknown ``type`` raises WireError with reason ``type`` (subscribers ignore it).
    """
    msg = _unpack(payload)
    mtype = _field(msg, "type", str, "a string")
    if mtype == "frame":
        return _frame_from_map(msg, skeletons)
    if mtype == "skeleton":
        return _skeleton_from_map(msg)
    raise WireError(f"unknown message type {mtype!r} (known: 'frame', 'skeleton')", "type")
