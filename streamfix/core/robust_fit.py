"""Stage 1 of the window cleaner: a robust local quadratic per coordinate channel.

Tukey-biweight iteratively reweighted local quadratics (:mod:`streamfix.core.local_poly`)
with a graduated scale (wide basin first, then sharper), started from a running median:
the clean samples, which lie on a smooth curve, are the mode of the residuals even when
most entries are corrupted, which a redescending M-estimator finds (see
:mod:`streamfix.core.pipeline` for how the cleaner uses it). :func:`robust_temporal_fit`
is the numpy reference of the compiled :func:`streamfix.core.kernels.robust_temporal_fit`.
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .filters import running_median
from .local_poly import fit_local_quadratic

__all__ = ["robust_temporal_fit", "robust_fit"]


def robust_temporal_fit(
    positions: np.ndarray,
    weights: np.ndarray,
    h: int,
    scales_m: tuple[float, ...] = (0.10, 0.05, 0.02, 0.01),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 1 on ``(T, J, 3)`` with prior weights ``(T, J)`` (0 = missing).

    Returns ``(fit, residual, support)`` each ``(T, J, 3)``; ``fit`` is the robust local
    quadratic at each frame, ``residual = positions - fit`` (NaN where missing),
    ``support`` the kernel-weighted count of inliers behind each fit at the sharpest
    scale (0 where it left none: the fit there is the last scale's that had inliers).
    """
    x = np.asarray(positions, dtype=np.float64)
    n_frames, n_joints, _ = x.shape
    y = x.reshape(n_frames, 3 * n_joints)
    prior = np.repeat(np.asarray(weights, dtype=np.float64), 3, axis=1)
    prior = np.where(np.isfinite(y), prior, 0.0)
    obs = prior > 0
    y0 = np.where(obs, y, 0.0)
    # only the reweighting's start: the local quadratics that follow carry the trend at the
    # edges themselves (detrended edges here left the sensor protocol's noise-kind errors
    # unchanged, frame for frame, and would run once per candidate width)
    med = running_median(np.where(obs, y, np.nan), 2 * h + 1, detrend_edges=False)
    fit = np.where(np.isfinite(med), med, 0.0)
    support = np.zeros_like(y0)
    for c in scales_m:  # graduated non-convexity: wide basin first, then sharpen
        r = y0 - fit
        w = np.where(obs & (np.abs(r) < c), (1.0 - (r / c) ** 2) ** 2, 0.0) * prior
        new_fit, support = fit_local_quadratic(y0, w, h)
        # a sharper scale that leaves a frame no inlier at all has nothing to fit there (the
        # ridge alone gives 0, the camera's origin): the wider scale's estimate stands
        fit = np.where(support > 0, new_fit, fit)
    resid = np.where(obs, y0 - fit, np.nan)
    shape = (n_frames, n_joints, 3)
    return fit.reshape(shape), resid.reshape(shape), support.reshape(shape)


def robust_fit(positions, weights, h, scales_m):
    """:func:`robust_temporal_fit`, compiled when :data:`streamfix.core.kernels.COMPILED` (same math)."""
    fit = kernels.robust_temporal_fit if kernels.COMPILED else robust_temporal_fit
    return fit(positions, weights, h, scales_m)
