"""What the service does with bad input: name the reason, count it, skip it.

Every frame that enters ``streamfix serve`` (from any source) passes
:func:`validate_frame`. A message that cannot be used raises :class:`BadInput` with
one of :data:`REASONS`; the service counts it under that reason
(``streamfix_malformed_total{reason=...}``), logs one line and goes on with the next
message, so good frames around a bad one are never lost.

NaN/inf coordinates are **not** an error: the joint is missing (NaN, confidence 0),
as everywhere in streamfix; they are counted in ``streamfix_nonfinite_joints_total``.
"""
from __future__ import annotations

import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..skeletons import Skeleton, get_skeleton

__all__ = ["BadInput", "REASONS", "validate_frame"]

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
