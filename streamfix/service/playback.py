"""Playing a recorded :class:`~streamfix.motion.Motion` as a live stream of frames.

Used by the ``replay:FILE`` source of ``streamfix serve`` and by ``streamfix replay``.

Timing: frame ``i`` (looped ``k`` times) is due at
``start + (t_i - t_0 + k * period) / rate`` on the **monotonic** clock, where
``period`` is the recording's duration plus one nominal frame interval. Every due
time is computed from the fixed ``start``, never from the previous send, so sleep
overshoot does not accumulate into drift: a late frame is sent at once and the next
one is still scheduled at its own absolute time. ``rate=inf`` sends as fast as the
consumer takes them.
"""
from __future__ import annotations

import math
import time
from typing import Iterator

import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..motion import Motion

__all__ = ["motion_frames", "Pacer", "load_recording"]


def load_recording(path: str) -> Motion:
    """Read any recording ``streamfix.io.read_motion`` understands (Kinect CSV, BVH, C3D, .sfrec)."""
    from ..io import read_motion

    return read_motion(path)


def motion_frames(
    motion: Motion,
    stream_id: str,
    *,
    body_id: int = 0,
    loop: bool = False,
    seq0: int = 0,
) -> Iterator[tuple[float, SkeletonFrame]]:
    """Yield ``(t_rel_s, frame)`` for every frame: ``t_rel_s`` is the offset (s) from the first.

    Sequence numbers count on from ``seq0`` across loops; sensor times (ns) keep
    increasing across loops (each loop is shifted by one recording period), so a
    looped replay looks like one continuous stream. Missing joints are NaN with
    confidence 0 (as in the motion).
    """
    ts = np.asarray(motion.timestamps, dtype=np.float64)
    if ts.size == 0:
        return
    rel = ts - ts[0]
    period = float(rel[-1]) + 1.0 / motion.rate_hz
    t0_ns = int(round(ts[0] * 1e9))
    name = motion.skeleton.name
    seq = int(seq0)
    k = 0
    while True:
        offset = k * period
        for i in range(motion.n_frames):
            t_rel = float(rel[i]) + offset
            body = BodyFrame(
                body_id=body_id,
                positions=motion.positions[i].copy(),
                confidence=motion.confidence[i].copy(),
            )
            yield t_rel, SkeletonFrame(
                stream_id=stream_id,
                seq=seq,
                sensor_time_ns=t0_ns + int(round(t_rel * 1e9)),
                skeleton=name,
                bodies=[body],
            )
            seq += 1
        k += 1
        if not loop:
            return


class Pacer:
    """Drift-free scheduler: when is an item with relative time ``t_rel`` (s) due?

    ``rate`` is the speed-up (1 = real time, 2 = twice as fast, ``inf`` = no waiting).
    """

    def __init__(self, rate: float = 1.0, clock=time.monotonic) -> None:
        if not rate > 0:
            raise ValueError(f"rate must be > 0 (1 = real time), got {rate}")
        self.rate = float(rate)
        self._clock = clock
        self._start: float | None = None

    def due(self, t_rel: float) -> float:
        """Monotonic time (s) at which ``t_rel`` is due; starts the clock on first call."""
        if self._start is None:
            self._start = self._clock()
        if math.isinf(self.rate):
            return self._start
        return self._start + t_rel / self.rate

    def wait_time(self, t_rel: float) -> float:
        """Seconds to wait until ``t_rel`` is due (0 when it is already due or late)."""
        return max(0.0, self.due(t_rel) - self._clock())

    def sleep_until(self, t_rel: float) -> None:
        delay = self.wait_time(t_rel)
        if delay > 0:
            time.sleep(delay)
