"""Resource limits of ``streamfix serve``: what one producer may cost the service.

Every limit has a safe default and a ``serve`` option; every time one is hit the
service counts it (``streamfix_limit_hits_total{limit=...}``, labels :data:`LIMITS`),
logs one rate-limited line and carries on with the rest of its input. The defaults
bound the memory a hostile or broken producer can make the service hold: the
streaming engine keeps a few seconds of every tracked body at the stream's rate
(its memory grows with the body's joints x rate), so the
tracked bodies' joints x rate (``max_joint_rate``), with the body and stream counts,
bound the engines' memory, and the message size
bounds what decoding one message can allocate.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

__all__ = ["Limits", "LIMITS"]

#: Labels of ``streamfix_limit_hits_total``: which limit a message or body ran into.
LIMITS: tuple[str, ...] = (
    "message_size",      # a message over max_message_bytes (rejected before decoding)
    "joints",            # a skeleton message with more than max_joints joints
    "name",              # a skeleton name longer than max_name_chars
    "builtin_skeleton",  # a skeleton message redefining a built-in skeleton name
    "bodies_frame",      # a frame with more than max_bodies_per_frame bodies (rejected)
    "bodies_stream",     # a new body id beyond max_bodies_per_stream / max_bodies_total / max_joint_rate (dropped)
    "streams",           # a frame of a new stream beyond max_streams (rejected)
    "rate",              # a sensor rate outside [min_rate_hz, max_rate_hz] (rejected)
    "coordinate",        # a joint coordinate beyond max_coordinate_m (joint made missing)
    "announcements",     # skeleton messages of streams that never sent a frame (oldest forgotten)
    "restart",           # a stream restart inside restart_cooldown_s (the frame is skipped as late)
)


@dataclass(frozen=True)
class Limits:
    """Per-service resource limits (bytes, counts, Hz, metres, seconds).

    max_message_bytes: largest input message (ZeroMQ ``MAXMSGSIZE`` on the PULL socket
    and a length check on every source). max_joints: joints of an announced skeleton.
    max_name_chars: length of an announced skeleton name. max_bodies_per_frame: bodies
    in one frame. max_bodies_per_stream / max_bodies_total: body ids tracked at once
    by one stream / by all streams (a body counts until ``body_ttl_s`` of sensor time
    after it was last seen). max_joint_rate: the sum over tracked bodies of joints x
    stream rate (joint-samples per second; what the engines' memory grows with).
    max_streams: streams with a running engine.
    min_rate_hz / max_rate_hz: accepted sensor rates. max_coordinate_m: a joint with a
    coordinate of larger magnitude is treated as missing (a sensor reports metres
    within a few tens of metres). max_announcements: skeleton messages remembered for
    streams that have not sent a frame yet. restart_cooldown_s: after a stream's engine
    restarts (producer restart, duplicate producers), frames that would restart it again
    within this time are skipped as late instead.
    """

    max_message_bytes: int = 256 * 1024
    max_joints: int = 1024
    max_name_chars: int = 64
    max_bodies_per_frame: int = 16
    max_bodies_per_stream: int = 16
    max_bodies_total: int = 64
    max_joint_rate: float = 200_000.0
    body_ttl_s: float = 2.0
    max_streams: int = 16
    min_rate_hz: float = 1.0
    max_rate_hz: float = 240.0
    max_coordinate_m: float = 50.0
    max_announcements: int = 64
    restart_cooldown_s: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not value > 0:
                raise ValueError(f"limit {f.name} must be > 0, got {value!r}")
        if self.min_rate_hz > self.max_rate_hz:
            raise ValueError(f"min_rate_hz {self.min_rate_hz} is above max_rate_hz {self.max_rate_hz}")
        if self.max_bodies_per_frame > 64:
            raise ValueError(f"max_bodies_per_frame is at most 64 (the wire limit), got {self.max_bodies_per_frame}")
