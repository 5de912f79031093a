"""Several one-body recordings as one multi-body stream (a ``.sfrec``), to exercise the viewer.

The viewer must keep up with several bodies at a sensor's rate; real multi-person
recordings are not in ``../shared/data``, so :func:`write_crowd_recording` places real
one-body takes side by side (body ``k`` shifted by ``spacing_m`` along x, centred),
cut to the shortest take and timed at its frame rate, as the ``raw`` frames of one
stream. ``streamfix replay`` plays the result (``--loop`` for longer runs).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..frames import BodyFrame, SkeletonFrame

__all__ = ["write_crowd_recording"]


def write_crowd_recording(sources: list[str | Path], out: str | Path, *, stream_id: str = "crowd",
                          spacing_m: float = 0.9) -> int:
    """Write ``out`` (.sfrec) with one body per source; returns the number of frames."""
    from ..io import read_motion
    from ..io.recording import RecordingWriter

    motions = [read_motion(p) for p in sources]
    if not motions:
        raise ValueError("write_crowd_recording needs at least one source recording")
    skeleton = motions[0].skeleton
    for p, m in zip(sources, motions):
        if m.skeleton.name != skeleton.name:
            raise ValueError(f"{p}: skeleton {m.skeleton.name!r}, expected {skeleton.name!r} like {sources[0]}")
    n = min(m.n_frames for m in motions)
    rate = motions[0].rate_hz
    shifts = (np.arange(len(motions)) - (len(motions) - 1) / 2.0) * spacing_m
    bodies = []
    for m, dx in zip(motions, shifts):
        pos = m.positions[:n].copy()
        pos[..., 0] += dx - np.nanmean(pos[..., 0])
        bodies.append((pos, m.confidence[:n]))
    t_ns = (np.arange(n) * (1e9 / rate)).astype(np.int64)
    with RecordingWriter(out, overwrite=True) as w:
        w.write_skeleton(stream_id, skeleton, rate, recv_time_ns=int(t_ns[0]))
        for i in range(n):
            frame = SkeletonFrame(stream_id, i, int(t_ns[i]), skeleton.name,
                                  [BodyFrame(k + 1, pos[i], conf[i]) for k, (pos, conf) in enumerate(bodies)])
            w.write_frame("raw", frame, recv_time_ns=int(t_ns[i]))
    return n
