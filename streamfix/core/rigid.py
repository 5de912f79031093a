"""Rigid transforms between two measurement systems, fitted by least squares.

Two recordings of one movement (a depth sensor and optical motion capture) live in
different coordinate frames. Comparing them needs the rotation ``A`` and translation
``b`` with ``y ~ A x + b``:

* :func:`fit_rigid` -- weighted Kabsch/Umeyama without scale: minimises
  ``sum_i w_i |A x_i + b - y_i|^2`` over rotations ``A`` (det +1) and ``b`` in closed
  form from the SVD of the weighted cross-covariance.
* :func:`fit_rigid_with_offsets` -- the same when each observed point sits at an
  unknown constant offset ``o_k`` in the frame of a tracked rigid body (a marker
  cluster on a segment, not the joint centre the sensor reports):
  ``y_k(t) ~ A (R_k(t) o_k + p_k(t)) + b``. Alternating least squares: with ``A, b``
  fixed the offsets are linear (``o_k`` = weighted mean of ``R_k(t)^T (A^T (y - b) - p)``),
  with the offsets fixed it is :func:`fit_rigid`. Samples whose residual exceeds
  ``outlier_factor`` x the median (and ``min_outlier_m``) are dropped after a few
  rounds, so a sensor's gross tracking failures (a hand 1 m off for a frame) do not
  pull the alignment.

Arrays in, arrays out; metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["fit_rigid", "fit_rigid_with_offsets", "OffsetFit"]


def fit_rigid(x: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``A`` (3, 3) and translation ``b`` (3,) minimising ``sum w |A x + b - y|^2``.

    ``x``, ``y``: ``(N, 3)`` corresponding points (NaN rows are ignored); ``weights``
    ``(N,)`` >= 0 (None = 1). Needs three non-collinear points with weight.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"expected two (N, 3) arrays of equal shape, got {x.shape} and {y.shape}")
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64).copy()
    if w.shape != (len(x),):
        raise ValueError(f"weights must be ({len(x)},), got {w.shape}")
    ok = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1) & (w > 0)
    if ok.sum() < 3:
        raise ValueError(f"a rigid fit needs at least 3 weighted point pairs, got {int(ok.sum())}")
    w, x, y = w[ok] / w[ok].sum(), x[ok], y[ok]
    mx, my = w @ x, w @ y
    H = ((x - mx) * w[:, None]).T @ (y - my)  # 3x3 cross-covariance
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0  # a reflection is not a rigid motion
    A = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return A, my - A @ mx


@dataclass
class OffsetFit:
    """Result of :func:`fit_rigid_with_offsets`.

    ``rotation`` (3, 3) and ``translation`` (3,) map the bodies' frame into the
    points' frame; ``offsets`` (K, 3) in each body's own frame (m); ``residuals``
    (T, K) m (NaN where a sample is missing); ``inliers`` (T, K) the samples within
    the outlier cut of the final fit.
    """

    rotation: np.ndarray
    translation: np.ndarray
    offsets: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray

    def reference(self, body_rotations: np.ndarray, body_positions: np.ndarray) -> np.ndarray:
        """``(T, K, 3)`` points ``A (R_k o_k + p_k) + b`` for body poses in the fitted frame."""
        q = body_positions + np.einsum("tkij,kj->tki", body_rotations, self.offsets)
        return q @ self.rotation.T + self.translation


def fit_rigid_with_offsets(
    points: np.ndarray,
    body_rotations: np.ndarray,
    body_positions: np.ndarray,
    *,
    iterations: int = 60,
    outlier_factor: float = 5.0,
    min_outlier_m: float = 0.05,
) -> OffsetFit:
    """Fit ``points`` ``(T, K, 3)`` ~ ``A (R_k(t) o_k + p_k(t)) + b`` (alternating LS).

    ``body_rotations`` ``(T, K, 3, 3)`` and ``body_positions`` ``(T, K, 3)`` (m) are the
    pose of the rigid body each point is attached to; NaN samples are ignored.
    Starts from zero offsets; outlier rejection begins after 5 rounds.
    """
    y = np.asarray(points, dtype=np.float64)
    R = np.asarray(body_rotations, dtype=np.float64)
    p = np.asarray(body_positions, dtype=np.float64)
    if y.ndim != 3 or y.shape[2] != 3 or p.shape != y.shape or R.shape != y.shape + (3,):
        raise ValueError(
            f"expected points (T, K, 3), body_positions (T, K, 3), body_rotations (T, K, 3, 3); "
            f"got {y.shape}, {p.shape}, {R.shape}"
        )
    valid = np.isfinite(y).all(axis=2) & np.isfinite(p).all(axis=2) & np.isfinite(R).all(axis=(2, 3))
    y0, p0 = np.where(valid[..., None], y, 0.0), np.where(valid[..., None], p, 0.0)
    R0 = np.where(valid[..., None, None], R, 0.0)
    offsets = np.zeros((y.shape[1], 3))
    inl = valid.copy()
    for it in range(iterations):
        q = p0 + np.einsum("tkij,kj->tki", R0, offsets)                       # body points
        A, b = fit_rigid(q[inl], y0[inl])                                      # A q + b ~ y
        local = np.einsum("tkji,tkj->tki", R0, (y0 - b) @ A - p0)              # R^T (A^T (y - b) - p)
        n = np.maximum(inl.sum(axis=0), 1)[:, None]
        offsets = (local * inl[..., None]).sum(axis=0) / n                     # LS offsets
        q = p0 + np.einsum("tkij,kj->tki", R0, offsets)
        resid = np.linalg.norm(q @ A.T + b - y0, axis=2)
        if it >= 5:
            cut = max(outlier_factor * float(np.median(resid[valid])), min_outlier_m)
            inl = valid & (resid <= cut)
    residuals = np.where(valid, resid, np.nan)
    return OffsetFit(A, b, offsets, residuals, inl)
