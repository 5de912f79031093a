"""Motion-level frame-rate conversion (wraps :mod:`streamfix.core.resample`)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..core.resample import resample_plan, resample_positions
from ..motion import Motion

__all__ = ["resample_motion"]


def resample_motion(motion: Motion, rate_hz: float) -> Motion:
    """``motion`` as a ``rate_hz`` sensor would have sampled it (see core.resample).

    Integer decimation (120 -> 30 Hz) keeps every k-th frame with its original
    timestamp and confidence; other ratios interpolate linearly, timestamps become
    ``t0 + i / rate_hz`` and confidence the lower of the two source frames'.
    """
    a, b, w = resample_plan(motion.n_frames, motion.rate_hz, rate_hz)
    pos, obs = resample_positions(motion.positions, motion.rate_hz, rate_hz, motion.observed)
    conf = np.where(w[:, None] > 0, np.minimum(motion.confidence[a], motion.confidence[b]), motion.confidence[a])
    conf = np.where(obs, conf, 0.0)
    if np.all(a == b):
        ts = motion.timestamps[a]
    else:
        ts = motion.timestamps[0] + np.arange(len(a)) / float(rate_hz)
    rec = None
    if motion.recovered is not None:
        rec = motion.recovered[a] | (motion.recovered[b] & (w[:, None] > 0))
    meta = dict(motion.meta)
    meta["resampled_from_hz"] = motion.rate_hz
    return replace(motion, positions=pos, confidence=conf, timestamps=ts, rate_hz=float(rate_hz), recovered=rec, meta=meta)
