"""Playing a recording as a live stream of frames (``replay:FILE`` and ``streamfix replay``).

:func:`open_playback` reads any recording: Kinect v2 CSV, BVH, C3D through
``streamfix.io.read_motion`` (one body, stream id = the file name), and the project's
``.sfrec`` frame by frame, so a recorded session keeps all its bodies, streams,
stream ids and skeleton messages (of a recording holding several topic kinds, the
``raw`` frames are played, else ``clean``, else ``live``; frames the service had
synthesised for sensor drops are left out, a service re-creates them).

Timing: frame ``i`` (looped ``k`` times) is due at
``start + (t_i - t_0 + k * period) / rate`` on the **monotonic** clock, where ``t_i``
is the frame's sensor time (for ``.sfrec``: the recorder's receive time when it has
one, so several streams keep their interleaving) and ``period`` is the recording's
duration plus one nominal frame interval. Every due time is computed from the fixed
``start``, never from the previous send, so sleep overshoot does not accumulate into
drift: a late frame is sent at once and the next one is still scheduled at its own
absolute time. ``rate=inf`` sends as fast as the consumer takes them. Looping keeps
``seq`` and sensor times increasing, so a looped replay is one continuous stream.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ..frames import SkeletonFrame
from ..motion import Motion
from ..skeletons import Skeleton

__all__ = ["motion_frames", "Pacer", "Playback", "open_playback", "stream_id_from_path"]


def stream_id_from_path(path: str | Path) -> str:
    """A valid stream id from a file name (``[A-Za-z0-9_.:-]``, at most 64 characters)."""
    stem = Path(path).stem
    safe = "".join(c if (c.isalnum() or c in "_.:-") else "_" for c in stem)[:64]
    return safe or "replay"


def motion_frames(
    motion: Motion,
    stream_id: str,
    *,
    body_id: int = 0,
    loop: bool = False,
    seq0: int = 0,
) -> Iterator[tuple[float, SkeletonFrame]]:
    """Yield ``(t_rel_s, frame)`` for every frame: ``t_rel_s`` is the offset (s) from the first.

    Frames as ``streamfix.streaming.offline.motion_frames`` makes them (what
    ``streamfix clean`` feeds its engine); each loop continues ``seq`` and shifts the
    sensor time (ns) by one recording period.
    """
    from ..streaming.offline import motion_frames as one_pass

    if motion.n_frames == 0:
        return
    ts = np.asarray(motion.timestamps, dtype=np.float64)
    period_ns = int(round((ts[-1] - ts[0] + 1.0 / motion.rate_hz) * 1e9))
    t0_ns = int(round(ts[0] * 1e9))
    k = 0
    while True:
        for frame in one_pass(motion, stream_id, body_id, seq0 + k * motion.n_frames):
            frame.sensor_time_ns += k * period_ns
            yield (frame.sensor_time_ns - t0_ns) / 1e9, frame
        k += 1
        if not loop:
            return


@dataclass
class Playback:
    """A recording ready to play: skeleton announcements, then timed frames."""

    path: str
    announce: list[tuple[str, Skeleton, float]]  # (stream id, skeleton, rate Hz)
    n_frames: int
    rate_hz: float
    make_frames: Callable[[bool], Iterator[tuple[float, SkeletonFrame]]] = field(repr=False)
    bodies: int = 1

    def frames(self, loop: bool = False) -> Iterator[tuple[float, SkeletonFrame]]:
        return self.make_frames(loop)

    def describe(self) -> str:
        streams = ", ".join(sorted({a[0] for a in self.announce}))
        skeletons = ", ".join(sorted({a[1].name for a in self.announce}))
        return (
            f"{self.path} ({self.n_frames} frames at {self.rate_hz:g} Hz, stream {streams}, "
            f"skeleton {skeletons}, up to {self.bodies} bodies)"
        )


def open_playback(path: str | Path, *, stream_id: str | None = None, body_id: int = 0) -> Playback:
    """Open any readable recording for playing (see module docstring)."""
    path = str(path)
    if path.lower().endswith(".sfrec"):
        return _sfrec_playback(path, stream_id)
    from ..io import read_motion

    motion = read_motion(path)
    if motion.n_frames == 0:
        raise ValueError(f"{Path(path).name}: the recording has no frames")
    sid = stream_id or stream_id_from_path(path)
    return Playback(
        path, [(sid, motion.skeleton, motion.rate_hz)], motion.n_frames, motion.rate_hz,
        lambda loop: motion_frames(motion, sid, body_id=body_id, loop=loop),
    )


def _sfrec_playback(path: str, stream_id: str | None) -> Playback:
    from ..io.recording import read_recording_contents

    contents = read_recording_contents(path)
    present = set(contents.kinds)
    kind = next((k for k in ("raw", "clean", "live") if k in present), None)
    if kind is None:
        raise ValueError(f"{Path(path).name}: the recording holds no frames")
    picked = [
        (f, t) for f, k, t in zip(contents.frames, contents.kinds, contents.recv_time_ns) if k == kind and not f.filled
    ]
    streams = sorted({f.stream_id for f, _ in picked})
    if stream_id is not None and len(streams) > 1:
        raise ValueError(f"{Path(path).name}: --stream-id needs a one-stream recording, this one has {streams}")
    rename = (lambda s: stream_id) if stream_id is not None else (lambda s: s)
    announce = []
    for s in streams:
        msg = contents.skeletons.get(s)
        if msg is not None:
            announce.append((rename(s), msg.skeleton, msg.rate_hz))
    rate = announce[0][2] if announce else 30.0
    # one clock for all streams: the recorder's receive time when every frame has one
    use_recv = all(t > 0 for _, t in picked)
    first_sensor = {}
    for f, _ in picked:
        first_sensor.setdefault(f.stream_id, f.sensor_time_ns)
    clock = np.array(
        [t if use_recv else f.sensor_time_ns - first_sensor[f.stream_id] for f, t in picked], dtype=np.int64
    )
    clock -= clock.min()
    span_ns = int(clock.max()) + int(round(1e9 / rate))
    seq_span = {s: 0 for s in streams}
    for f, _ in picked:
        seq_span[f.stream_id] = max(seq_span[f.stream_id], f.seq + 1)

    def frames(loop: bool) -> Iterator[tuple[float, SkeletonFrame]]:
        k = 0
        while True:
            for (f, _), c in zip(picked, clock):
                out = copy.copy(f)
                out.stream_id = rename(f.stream_id)
                out.seq = f.seq + k * seq_span[f.stream_id]
                out.sensor_time_ns = f.sensor_time_ns + k * span_ns
                out.publish_time_ns = 0
                yield (int(c) + k * span_ns) / 1e9, out
            k += 1
            if not loop:
                return

    bodies = max((len(f.bodies) for f, _ in picked), default=0)
    return Playback(path, announce, len(picked), rate, frames, bodies)


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
