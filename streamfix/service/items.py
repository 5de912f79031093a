"""What a source hands the service loop: one item per received message, already judged.

A source never raises on bad input: each message becomes a :class:`Frame` (a raw frame
with its arrival time), an :class:`Announce` (a skeleton layout), a :class:`Rejected`
(malformed, with the reason the service counts), a :class:`Limited` (over a resource
limit) or a :class:`Shed` (frames dropped unprocessed, counted). :func:`wire_reason`
maps a wire decoding error to the service's malformed-input reason.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Union

from ..frames import SkeletonFrame
from ..skeletons import Skeleton

__all__ = ["Frame", "Announce", "Rejected", "Shed", "Limited", "Item", "wire_reason"]


@dataclass
class Frame:
    """A raw frame, with its arrival time on the monotonic clock (ns). ``newest``: no later
    frame of its stream waited in the backlog when it was taken, so it is not shed for its
    age (live shows the latest pose a stream sent)."""

    frame: SkeletonFrame
    arrival_ns: int
    rate_hz: float | None = None
    newest: bool = True


@dataclass
class Announce:
    """A skeleton layout announced on the input (wire skeleton message)."""

    stream_id: str
    skeleton: Skeleton
    rate_hz: float
    registered: bool = False  # already checked and stored in the source's SkeletonScope


@dataclass
class Rejected:
    """A message that was skipped: ``reason`` from ``validate.REASONS``, ``detail`` for the log."""

    reason: str
    detail: str


# WireError.reason -> service reason (the label of streamfix_malformed_total).
_WIRE_REASONS = {
    "garbage": "garbage",
    "truncated": "truncated",
    "version": "newer_version",
    "skeleton": "unknown_skeleton",
    "joints": "wrong_joint_count",
    "type": "invalid",
    "field": "invalid",
}


def wire_reason(exc: Exception) -> str:
    """Map a ``WireError`` to the service's malformed-input reason."""
    reason = _WIRE_REASONS.get(getattr(exc, "reason", ""), "invalid")
    if reason == "newer_version" and "newer" not in str(exc):
        reason = "invalid"  # version 0 or negative: not newer, just wrong
    return reason


@dataclass
class Shed:
    """Input frames of one stream dropped before decoding (overload or shutdown), counted."""

    stream_id: str | None  # None: messages without a topic, stream unknown
    count: int
    reason: str = "backlog"


@dataclass
class Limited:
    """A message over a resource limit (``limits.LIMITS``), skipped and counted."""

    limit: str
    detail: str


Item = Union[Frame, Announce, Rejected, Shed, Limited]
