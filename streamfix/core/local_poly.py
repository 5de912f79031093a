"""Zero-lag weighted local quadratic fits along time (the smoother every cleaning stage shares).

A tricube-weighted quadratic is fitted around every frame of each coordinate channel,
with per-sample weights (0 = missing or outlying). The window cleaner's robust fit
(:mod:`streamfix.core.robust_fit`), its noise-matched smoothing
(:mod:`streamfix.core.adaptive_smoothing`), short-gap filling
(:mod:`streamfix.core.window_gaps`) and the bone projection's correction smoothing
(:mod:`streamfix.core.bone_projection`) all use it. :func:`local_poly_numpy` is the numpy
reference of the compiled :func:`streamfix.core.kernels.local_poly`.

Arrays: ``y`` ``(T, C)`` (metres), ``w`` ``(T, C)`` weights; half-widths ``h`` in frames.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from . import kernels

__all__ = ["fit_local_quadratic", "local_poly_numpy", "residual_scale", "kernel_mass"]

_PIVOT_RTOL = 1e-4  # LDL^T pivot / diagonal below this: cancellation, solve by LU instead


def local_poly_numpy(y: np.ndarray, w: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Weighted local quadratic fit at every frame of ``y`` ``(T, C)`` with weights ``w``.

    Tricube kernel K(k) = (1 - (|k|/(h+1))^3)^3, k = -h..h. The normal equations
    sum_k K w (1, k, k^2)^T (1, k, k^2) a = sum_k K w y (1, k, k^2)^T are built by
    correlations along time (no loop over frames) and solved in closed form (LDL^T),
    elementwise over (T, C): cheaper than a batched ``np.linalg.solve`` of 3x3s.
    Returns ``(fit, support)`` with support = sum_k K(k) w(t+k).
    """
    k = np.arange(-h, h + 1, dtype=np.float64)
    K = (1.0 - (np.abs(k) / (h + 1)) ** 3) ** 3
    u = k / h  # scaled abscissa keeps the 3x3 systems well conditioned
    S = [correlate1d(w, K * u**m, axis=0, mode="constant") for m in range(5)]
    wy = w * y
    R = [correlate1d(wy, K * u**m, axis=0, mode="constant") for m in range(3)]
    # normal matrix M = [[S0, S1, S2], [S1, S2, S3], [S2, S3, S4]] + ridge: 1e-12 on the
    # constant, 1e-9 on slope/curvature (a lone sample gives a constant fit)
    m00 = S[0] + 1e-12
    m11 = S[2] + 1e-9
    m22 = S[4] + 1e-9
    m01, m02, m12 = S[1], S[2], S[3]
    # closed-form LDL^T of the symmetric 3x3 (elementwise over (T, C), no per-system
    # call overhead); only the constant a0 = fit is needed. M is positive definite.
    d0 = m00
    l10 = m01 / d0
    l20 = m02 / d0
    d1 = m11 - l10 * m01
    l21 = (m12 - l20 * m01) / d1
    d2 = m22 - l20 * m02 - l21 * l21 * d1
    z1 = R[1] - l10 * R[0]
    a2 = (R[2] - l20 * R[0] - l21 * z1) / d2
    a1 = z1 / d1 - l21 * a2
    fit = R[0] / d0 - l10 * a1 - l20 * a2
    # where elimination cancelled most digits of a pivot (a window holding one or two
    # weighted samples: the fit is then fixed by the tiny ridge), LDL^T and LU agree
    # only to ~1e-7 m; those systems keep LAPACK's LU with pivoting so the result is
    # the same as solving every system with it (< 1e-9 m apart; tested on real mocap)
    bad = (d1 < _PIVOT_RTOL * m11) | (d2 < _PIVOT_RTOL * m22)
    if bad.any():
        M = np.empty((int(bad.sum()), 3, 3))
        M[:, 0, 0], M[:, 1, 1], M[:, 2, 2] = m00[bad], m11[bad], m22[bad]
        M[:, 0, 1] = M[:, 1, 0] = m01[bad]
        M[:, 0, 2] = M[:, 2, 0] = m02[bad]
        M[:, 1, 2] = M[:, 2, 1] = m12[bad]
        rhs = np.stack([R[0][bad], R[1][bad], R[2][bad]], axis=-1)[..., None]
        fit[bad] = np.linalg.solve(M, rhs)[:, 0, 0]
    return fit, S[0]


def fit_local_quadratic(y: np.ndarray, w: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Zero-lag weighted local quadratic of ``y`` ``(T, C)`` at every frame, half-width ``h``
    frames (:func:`local_poly_numpy`; compiled when :data:`streamfix.core.kernels.COMPILED`, same
    math). Returns ``(fit, support)``."""
    return kernels.local_poly(y, w, h) if kernels.COMPILED else local_poly_numpy(y, w, h)


def residual_scale(y: np.ndarray, w: np.ndarray, h: int) -> float:
    """Robust scale (m) of the residual of a local quadratic fit of half-width ``h`` frames.

    White noise of std s leaves a residual of nearly the same scale whatever ``h``
    (a fraction that grows slowly with h); the bias of fitting real motion grows like
    h^4. The ratio of the scales at h = 4 and h = 2 therefore tells sensor noise
    (ratio ~1.3) from motion detail (ratio >> 2).
    """
    fit, _ = fit_local_quadratic(y, w, h)
    r = np.abs(y - fit)[w > 0]
    return float(1.4826 * np.median(r)) if r.size else 0.0


def kernel_mass(h: int) -> float:
    """Sum of the tricube kernel of half-width ``h`` frames (a local fit's support with every
    sample observed and weighted 1)."""
    k = np.arange(-h, h + 1)
    return float(np.sum((1.0 - (np.abs(k) / (h + 1)) ** 3) ** 3))
