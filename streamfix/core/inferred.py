"""Inferred samples that the body model contradicts give way to the model's fill.

Why: a depth sensor that loses a limb keeps reporting it, flagged *inferred*, from its
own guess: the limb freezes in its last pose, carried along by the body, or drifts off.
Nothing in the samples themselves says when the guess stopped matching the person
(a frozen limb is as smooth as a tracked one, and a still person's limbs *are* frozen),
but the rest of the body does: the fill the gap-bridging sources (PCA on the body's
history, the learned prior) make for the limb from the tracked joints. Where the
inferred samples stay near that fill they are kept (they carry detail the fill lacks);
where they part from it by more than the fill's own error, the fill takes over.

:func:`replacement_weight` gives, per inferred joint-frame, the weight of the fill:
``smoothstep((d - lo) / (hi - lo))`` of the distance ``d`` (metres) between the sample
and the fill, averaged over ``span`` frames (a decision for stretches, not samples) and
shared by a limb's joints (the largest over the limb: a limb fails as one piece).
Arrays: positions ``(T, J, 3)`` metres; masks ``(T, J)`` bool.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from .points import finite_points, point_norms

__all__ = ["replacement_weight", "tracked_proximity", "DISAGREE_M", "TRACKED_NEAR_S"]

DISAGREE_M = (0.10, 0.25)
"""Sample-to-fill distance (m) below which the inferred sample is kept whole, above
which the fill replaces it; between, a smooth blend. The lower end sits above the
fills' typical error on a missing limb (the prior's held-out fit: ``benchmarks/bench_prior.py``)."""


TRACKED_NEAR_S = (1.0, 2.0)
"""An inferred sample within the first of these many seconds of a tracked sample of the
same joint is questioned in full; beyond the second, not at all (no anchor for a fill)."""


def tracked_proximity(tracked: np.ndarray, rate_hz: float, near_s: tuple[float, float] = TRACKED_NEAR_S) -> np.ndarray:
    """``(T, J)`` in [0, 1]: 1 within ``near_s[0]`` s of a tracked sample of the joint
    (either side, within the array), fading smoothly to 0 at ``near_s[1]`` s."""
    trk = np.asarray(tracked, dtype=bool)
    T = trk.shape[0]
    idx = np.arange(T)[:, None]
    prev = np.maximum.accumulate(np.where(trk, idx, -10 * T), axis=0)
    nxt = np.minimum.accumulate(np.where(trk, idx, 11 * T)[::-1], axis=0)[::-1]
    gap_s = np.minimum(idx - prev, nxt - idx) / float(rate_hz)
    lo, hi = near_s
    z = np.clip((hi - gap_s) / max(hi - lo, 1e-12), 0.0, 1.0)
    return z * z * (3.0 - 2.0 * z)


def replacement_weight(
    inferred: np.ndarray,
    fill: np.ndarray,
    filled: np.ndarray,
    candidates: np.ndarray,
    limbs: list[np.ndarray] | None = None,
    *,
    span: int = 9,
    disagree_m: tuple[float, float] = DISAGREE_M,
) -> np.ndarray:
    """``(T, J)`` weight in [0, 1] of ``fill`` over the ``inferred`` samples.

    ``candidates``: joint-frames that are inferred (and long enough to question);
    ``filled``: where ``fill`` holds a value; ``limbs``: joint index arrays whose
    weights are shared (each frame's largest). 0 outside ``candidates & filled``.
    """
    x = np.asarray(inferred, dtype=np.float64)
    f = np.asarray(fill, dtype=np.float64)
    use = np.asarray(candidates, dtype=bool) & np.asarray(filled, dtype=bool)
    use &= finite_points(x) & finite_points(f)
    if not use.any():
        return np.zeros(use.shape)
    d = np.where(use, point_norms(np.nan_to_num(x - f)), 0.0)
    # a running mean over the usable samples only (0/0 where none)
    num = uniform_filter1d(d, size=max(1, int(span)), axis=0, mode="nearest")
    den = uniform_filter1d(use.astype(np.float64), size=max(1, int(span)), axis=0, mode="nearest")
    dm = np.divide(num, den, out=np.zeros_like(num), where=den > 1e-9)
    lo, hi = disagree_m
    z = np.clip((dm - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    w = z * z * (3.0 - 2.0 * z)
    for limb in limbs or ():
        limb = np.asarray(limb, dtype=np.intp)
        if limb.size:
            w[:, limb] = np.where(use[:, limb], np.max(np.where(use[:, limb], w[:, limb], 0.0), axis=1, keepdims=True), 0.0)
    return np.where(use, w, 0.0)
