"""One sensor frame of one stream: the unit that flows through the streaming layer.

These are transport-agnostic: the streaming engine consumes and produces them, the
wire module (``streamfix.transport.wire``) encodes them as msgpack, readers of
recordings yield them. Units: positions in metres, times in integer nanoseconds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .skeletons import Skeleton

__all__ = ["BodyFrame", "SkeletonFrame", "check_frame"]


@dataclass
class BodyFrame:
    """One tracked body in one frame.

    ``positions`` ``(J, 3)`` float64 metres, NaN where the joint is missing;
    ``confidence`` ``(J,)`` in [0, 1] (1 tracked, 0.5 inferred, 0 missing);
    ``recovered`` ``(J,)`` bool on cleaned output: True where the value was
    recovered (filled or replaced) rather than observed. None on raw input.
    """

    body_id: int
    positions: np.ndarray
    confidence: np.ndarray
    recovered: np.ndarray | None = None


@dataclass
class SkeletonFrame:
    """All bodies of one stream at one sensor instant.

    ``seq`` is the per-stream sequence number (consecutive, starting anywhere);
    ``sensor_time_ns`` the sensor clock; ``publish_time_ns`` the wall clock when
    published (0 until then); ``skeleton`` a registry name (see ``streamfix.skeletons``).
    ``filled`` is True for a frame the service synthesised for a sensor frame that
    never arrived (a timestamp gap): every joint in it is recovered.
    On the service's output, ``epoch`` identifies the run of ``seq`` numbering
    (0 = not stated; see ``protocol/SPEC.md``) and ``dropped`` counts the input frames
    of the stream the service shed under overload just before this instant.
    """

    stream_id: str
    seq: int
    sensor_time_ns: int
    skeleton: str
    bodies: list[BodyFrame] = field(default_factory=list)
    publish_time_ns: int = 0
    filled: bool = False
    epoch: int = 0
    dropped: int = 0


def check_frame(frame: SkeletonFrame, skeleton: Skeleton) -> None:
    """Raise ValueError naming what is wrong when ``frame`` does not fit ``skeleton``: another
    skeleton name, a body whose positions are not ``(J, 3)`` or whose confidences are not
    ``(J,)`` (with the expected J), or a body id that appears twice."""
    if frame.skeleton != skeleton.name:
        raise ValueError(
            f"stream {frame.stream_id!r} seq {frame.seq}: skeleton {frame.skeleton!r}, "
            f"this engine cleans {skeleton.name!r}"
        )
    J = skeleton.n_joints
    ids = set()
    for b in frame.bodies:
        pos = np.asarray(b.positions)
        conf = np.asarray(b.confidence)
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] != J:
            raise ValueError(
                f"stream {frame.stream_id!r} seq {frame.seq} body {b.body_id}: expected {J} joints "
                f"({skeleton.name}) as ({J}, 3) positions, got shape {pos.shape}"
            )
        if conf.shape != (J,):
            raise ValueError(
                f"stream {frame.stream_id!r} seq {frame.seq} body {b.body_id}: expected {J} "
                f"confidences ({skeleton.name}), got shape {conf.shape}"
            )
        if b.body_id in ids:
            raise ValueError(f"stream {frame.stream_id!r} seq {frame.seq}: body {b.body_id} appears twice")
        ids.add(b.body_id)
