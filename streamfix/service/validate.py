"""What the service does with bad input: name the reason, count it, skip it.

Every frame that enters ``streamfix serve`` (from any source) passes
:func:`validate_frame`. A message that cannot be used raises :class:`BadInput` with
one of :data:`REASONS`; the service counts it under that reason
(``streamfix_malformed_total{reason=...}``), logs one line and goes on with the next
message, so good frames around a bad one are never lost.

NaN/inf coordinates are **not** an error: the joint is missing (NaN, confidence 0),
as everywhere in streamfix; they are counted in ``streamfix_nonfinite_joints_total``.
Coordinates beyond a magnitude no sensor reports (:func:`limit_coordinates`) are
missing too, counted as the ``coordinate`` limit.

A message that is well formed but over one of the service's resource limits
(:mod:`streamfix.service.limits`) raises :class:`LimitHit` naming the limit; the
service counts it under ``streamfix_limit_hits_total{limit=...}``.
"""
from __future__ import annotations

import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..skeletons import AZURE_KINECT, KINECT_V2, MEDIAPIPE_POSE, Skeleton, get_skeleton
from .limits import LIMITS, Limits

__all__ = [
    "BadInput",
    "LimitHit",
    "REASONS",
    "BUILTIN_SKELETONS",
    "validate_frame",
    "limit_coordinates",
    "check_rate",
    "check_announcement",
    "short",
]

#: Skeleton names every receiver knows (SPEC section 5); no producer may redefine them.
BUILTIN_SKELETONS: dict[str, Skeleton] = {s.name: s for s in (KINECT_V2, AZURE_KINECT, MEDIAPIPE_POSE)}

#: Reasons a message is skipped (the ``reason`` label of ``streamfix_malformed_total``).
REASONS: tuple[str, ...] = (
    "garbage",            # not a message at all (not msgpack / JSON / CSV, or not a map)
    "truncated",          # the message ends early
    "wrong_joint_count",  # a body's joint array does not match the skeleton's joint count
    "unknown_skeleton",   # skeleton name neither registered nor announced by a meta message
    "newer_version",      # protocol version newer than this service understands
    "invalid",            # decodes, but a field is missing or of the wrong type/shape
)


class BadInput(Exception):
    """A message the service skips; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, detail: str) -> None:
        if reason not in REASONS:
            reason = "invalid"
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


class LimitHit(Exception):
    """A message or body over a resource limit; ``limit`` is one of ``limits.LIMITS``."""

    def __init__(self, limit: str, detail: str) -> None:
        if limit not in LIMITS:
            raise ValueError(f"unknown limit {limit!r}; expected one of {', '.join(LIMITS)}")
        super().__init__(f"{limit}: {detail}")
        self.limit = limit
        self.detail = detail


def short(text: object, n: int = 80) -> str:
    """``repr`` of a value cut to ``n`` characters, for log lines (names may be megabytes)."""
    r = repr(text)
    return r if len(r) <= n else f"{r[:n]}...({len(r)} chars)"


def check_rate(stream_id: str, rate_hz: float, limits: Limits) -> float:
    """The stream's sensor rate if inside ``[min_rate_hz, max_rate_hz]``, else LimitHit.

    The engine sizes its per-body buffers in seconds at this rate, so the rate bounds
    the memory one body costs.
    """
    rate = float(rate_hz)
    if not limits.min_rate_hz <= rate <= limits.max_rate_hz:  # NaN fails too
        raise LimitHit(
            "rate",
            f"stream {stream_id!r}: sensor rate {rate:g} Hz is outside the accepted "
            f"{limits.min_rate_hz:g}..{limits.max_rate_hz:g} Hz (serve --max-rate)",
        )
    return rate


def check_announcement(stream_id: str, skeleton: Skeleton, rate_hz: float, limits: Limits) -> None:
    """Raise LimitHit if a producer's skeleton message may not be used.

    A built-in name may be announced only with its built-in layout (a producer must
    not change how other streams' frames decode); the name length, the joint count
    and the rate are bounded.
    """
    if len(skeleton.name) > limits.max_name_chars:
        raise LimitHit("name", f"stream {stream_id!r}: skeleton name of {len(skeleton.name)} characters, "
                               f"at most {limits.max_name_chars}: {short(skeleton.name, 40)}")
    builtin = BUILTIN_SKELETONS.get(skeleton.name)
    if builtin is not None and builtin != skeleton:
        raise LimitHit("builtin_skeleton", f"stream {stream_id!r}: skeleton message redefines the built-in "
                                           f"{skeleton.name!r} ({builtin.n_joints} joints) with "
                                           f"{skeleton.n_joints} joints; built-in names cannot be redefined")
    if skeleton.n_joints > limits.max_joints:
        raise LimitHit("joints", f"stream {stream_id!r}: skeleton {short(skeleton.name, 40)} has "
                                 f"{skeleton.n_joints} joints, at most {limits.max_joints}")
    check_rate(stream_id, rate_hz, limits)


def limit_coordinates(frame: SkeletonFrame, max_m: float) -> int:
    """Make joints with a coordinate beyond ``max_m`` metres missing; return how many.

    A finite but absurd value (3e38 m) is a corrupt sample, not a position: passed on,
    it would pull the filters and the solver far away for seconds.
    """
    far = 0
    for body in frame.bodies:
        bad = (np.abs(body.positions) > max_m).any(axis=1)  # NaN compares False: already missing
        n = int(bad.sum())
        if n:
            body.positions = body.positions.copy()
            body.positions[bad] = np.nan
            body.confidence = np.where(bad, 0.0, body.confidence)
            far += n
    return far


def validate_frame(frame: SkeletonFrame, skeletons: dict[str, Skeleton] | None = None) -> tuple[SkeletonFrame, int]:
    """Check a decoded frame against its skeleton; return it (sanitised) and its non-finite joint count.

    ``skeletons`` are layouts announced on the input (meta messages) in addition to
    the registry. Non-finite coordinates become NaN with confidence 0; confidences
    are clipped to [0, 1]. Raises :class:`BadInput` for an unknown skeleton or a
    body whose arrays do not have the skeleton's joint count.
    """
    skel = (skeletons or {}).get(frame.skeleton)
    if skel is None:
        try:
            skel = get_skeleton(frame.skeleton)
        except KeyError as exc:
            raise BadInput("unknown_skeleton", str(exc.args[0]) if exc.args else repr(frame.skeleton)) from None
    n = skel.n_joints
    nonfinite = 0
    bodies: list[BodyFrame] = []
    for body in frame.bodies:
        pos = np.asarray(body.positions, dtype=np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] != n:
            got = pos.shape[0] if pos.ndim >= 1 else 0
            raise BadInput(
                "wrong_joint_count",
                f"stream {frame.stream_id!r} seq {frame.seq} body {body.body_id}: skeleton "
                f"{skel.name!r} has {n} joints, the message has {got} (positions shape {pos.shape})",
            )
        conf = np.asarray(body.confidence, dtype=np.float64).reshape(-1)
        if conf.shape[0] != n:
            raise BadInput(
                "wrong_joint_count",
                f"stream {frame.stream_id!r} seq {frame.seq} body {body.body_id}: skeleton "
                f"{skel.name!r} has {n} joints, confidence has {conf.shape[0]} values",
            )
        finite = np.isfinite(pos).all(axis=1)
        nonfinite += int((~finite).sum())
        conf = np.where(np.isfinite(conf), np.clip(conf, 0.0, 1.0), 0.0)
        conf[~finite] = 0.0
        pos = pos.copy()
        pos[~finite | (conf <= 0)] = np.nan
        bodies.append(BodyFrame(body_id=int(body.body_id), positions=pos, confidence=conf, recovered=body.recovered))
    frame.bodies = bodies
    return frame, nonfinite
