"""Text input for ``streamfix serve --source stdin``: Kinect v2 CSV lines or JSON lines.

Each line is one frame; the format is detected per line (a line starting with ``{``
is JSON, anything else is CSV), so the two may even be mixed. Blank lines and lines
starting with ``#`` are ignored.

**Kinect v2 CSV** (the format of the Kinect v2 recordings, one line per frame)::

    ticks, x0, y0, z0, state0, ..., x24, y24, z24, state24[,]

``ticks`` is the sensor time in 100 ns ticks; positions in metres (camera space);
``state`` 2 = tracked (confidence 1), 1 = inferred (0.5), 0 = not tracked (missing).
The stream id is ``--stream-id`` (default ``stdin``), the sequence number counts lines
that parsed, the skeleton is ``kinect_v2``, and there is one body (id 0).

**JSON lines** (one object per line; every key but ``bodies`` is optional)::

    {"stream": "kinect0", "seq": 17, "sensor_time_ns": 566100000,
     "skeleton": "kinect_v2",
     "bodies": [{"body_id": 0,
                 "joints": [[x, y, z], ...],        # J rows, metres; null = missing
                 "confidence": [1.0, 0.5, ...]}]}   # optional, default 1 where finite

Accepted aliases: ``stream_id`` for ``stream``; ``t_sensor_ns`` / ``sensor_ns`` /
``t_ns`` for ``sensor_time_ns``, or ``t`` in seconds; ``id`` for ``body_id``;
``positions`` for ``joints``; a whole joint may be ``null`` (missing). Defaults: stream
``--stream-id``, seq = running count, sensor time = arrival time on the monotonic
clock, skeleton ``kinect_v2``. Other keys are ignored. So the lines ``streamfix tap
--json`` prints can be piped back into a service; its skeleton lines (``"type":
"skeleton"`` with ``skeleton``, ``joint_names``, ``bones``, ``rate_hz``) announce a
skeleton outside the registry, as the wire's skeleton message does.

Errors raise :class:`~streamfix.service.validate.BadInput` with a reason from
:data:`~streamfix.service.validate.REASONS`.
"""
from __future__ import annotations

import json
import math
import time

import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..skeletons import KINECT_V2, Skeleton
from ..transport.wire import SkeletonMessage
from .validate import BadInput

__all__ = ["parse_line", "parse_kinect_csv_line", "parse_json_line"]

_STATE_CONFIDENCE = {0: 0.0, 1: 0.5, 2: 1.0}


def parse_kinect_csv_line(line: str, stream_id: str, seq: int) -> SkeletonFrame:
    """One Kinect v2 CSV line -> frame (see module docstring)."""
    fields = [f.strip() for f in line.strip().rstrip(",").split(",")]
    try:
        values = [float(f) for f in fields]
    except ValueError:
        bad = next(f for f in fields if not _is_float(f))
        raise BadInput("garbage", f"Kinect CSV line has a non-numeric field {bad[:40]!r}") from None
    n = KINECT_V2.n_joints
    if len(values) != 1 + 4 * n:
        if len(values) > 1 and (len(values) - 1) % 4 == 0:
            raise BadInput(
                "wrong_joint_count",
                f"Kinect CSV line has {(len(values) - 1) // 4} joints, expected {n} for kinect_v2",
            )
        raise BadInput(
            "garbage",
            f"Kinect CSV line has {len(values)} fields, expected 1 + 4 x {n} = {1 + 4 * n}",
        )
    ticks = values[0]
    if not math.isfinite(ticks):
        raise BadInput("garbage", f"Kinect CSV timestamp is not a number: {fields[0]!r}")
    arr = np.asarray(values[1:], dtype=np.float64).reshape(n, 4)
    state = arr[:, 3]
    confidence = np.array([_STATE_CONFIDENCE.get(int(s), 0.0) if math.isfinite(s) else 0.0 for s in state])
    return SkeletonFrame(
        stream_id=stream_id,
        seq=int(seq),
        sensor_time_ns=int(round(ticks)) * 100,
        skeleton=KINECT_V2.name,
        bodies=[BodyFrame(body_id=0, positions=arr[:, :3].copy(), confidence=confidence)],
    )


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _first(obj: dict, *keys: str, default=None):
    for k in keys:
        if k in obj:
            return obj[k]
    return default


def _skeleton_line(obj: dict, stream_id: str) -> SkeletonMessage:
    try:
        skeleton = Skeleton(str(obj["skeleton"]), tuple(obj["joint_names"]), tuple(tuple(b) for b in obj["bones"]))
        rate = float(obj.get("rate_hz", 30.0))
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"rate_hz must be a positive number, got {rate}")
    except (KeyError, TypeError, ValueError) as exc:
        raise BadInput("invalid", f"JSON skeleton line is malformed: {exc!r}") from None
    return SkeletonMessage(str(_first(obj, "stream", "stream_id", default=stream_id)), skeleton, rate)


def parse_json_line(line: str, stream_id: str, seq: int) -> SkeletonFrame | SkeletonMessage:
    """One JSON-lines frame -> frame (see module docstring)."""
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as exc:
        text = line.rstrip()
        # cut short: no closing brace and the parser ran into the end (a number may be half there)
        reason = "truncated" if not text.endswith("}") and exc.pos >= len(text) - 16 else "garbage"
        raise BadInput(reason, f"JSON line does not parse: {exc.msg} at column {exc.colno}") from None
    except RecursionError:  # nesting deeper than the parser's stack: not a frame
        raise BadInput("garbage", "JSON line is nested too deeply to be a frame") from None
    if not isinstance(obj, dict):
        raise BadInput("garbage", f"JSON line is a {type(obj).__name__}, expected an object")
    if obj.get("type") == "skeleton":
        return _skeleton_line(obj, stream_id)
    bodies_in = obj.get("bodies")
    if not isinstance(bodies_in, list):
        raise BadInput("invalid", "JSON frame has no 'bodies' list")
    try:
        t_ns = _sensor_time_ns(obj)
        bodies = []
        for i, b in enumerate(bodies_in):
            joints = _first(b, "joints", "positions")
            if joints is None:
                raise BadInput("invalid", f"JSON body {i} has no 'joints'")
            pos = np.array(
                [[np.nan] * 3 if row is None else [np.nan if c is None else float(c) for c in row] for row in joints],
                dtype=np.float64,
            ).reshape(len(joints), -1)
            if pos.ndim != 2 or (pos.size and pos.shape[1] != 3):
                raise BadInput("invalid", f"JSON body {i}: joints must be [x, y, z] rows, got shape {pos.shape}")
            conf = b.get("confidence")
            conf = (
                np.isfinite(pos).all(axis=1).astype(np.float64)
                if conf is None
                else np.array([0.0 if c is None else float(c) for c in conf], dtype=np.float64)
            )
            bodies.append(
                BodyFrame(body_id=int(_first(b, "body_id", "id", default=i)), positions=pos.reshape(-1, 3), confidence=conf)
            )
        return SkeletonFrame(
            stream_id=str(_first(obj, "stream", "stream_id", default=stream_id)),
            seq=_whole_number(obj.get("seq", seq), "seq"),
            sensor_time_ns=t_ns,
            skeleton=str(obj.get("skeleton", KINECT_V2.name)),
            bodies=bodies,
        )
    except BadInput:
        raise
    except (TypeError, ValueError, AttributeError, OverflowError) as exc:
        raise BadInput("invalid", f"JSON frame has a malformed field: {exc}") from None


_INT64_MAX = 2**63 - 1


def _whole_number(value, name: str) -> int:
    """``value`` as an int that fits the wire's int64; ValueError naming ``name`` otherwise
    (a JSON ``1e400`` is inf, a ``null`` or a string is not a number)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value) or abs(value) > _INT64_MAX:
        raise ValueError(f"{name} must be a finite number within int64, got {value!r}")
    return int(value)


def _sensor_time_ns(obj: dict) -> int:
    """The frame's sensor time (ns) from its time key (``t`` in seconds), else the arrival
    time on the monotonic clock (module docstring)."""
    t_ns = _first(obj, "sensor_time_ns", "t_sensor_ns", "sensor_ns", "t_ns")
    if t_ns is not None:
        return _whole_number(t_ns, "sensor_time_ns")
    if "t" in obj:
        t = obj["t"]
        if isinstance(t, bool) or not isinstance(t, (int, float)):
            raise ValueError(f"t must be a number of seconds, got {t!r}")
        return _whole_number(t * 1e9, "t (s)")
    return time.monotonic_ns()


def parse_line(line: str, stream_id: str, seq: int) -> SkeletonFrame | SkeletonMessage | None:
    """Parse one stdin line (JSON or Kinect CSV); None for blank/comment lines."""
    text = line.strip()
    if not text or text.startswith("#"):
        return None
    if text.startswith("{"):
        return parse_json_line(text, stream_id, seq)
    return parse_kinect_csv_line(text, stream_id, seq)
