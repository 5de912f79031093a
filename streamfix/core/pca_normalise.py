"""Frames expressed in the frame of their observed joints, for PCA gap filling
(:mod:`streamfix.core.pca_gapfill`): the per-frame centroid of those joints removed and,
optionally, the frame rotated onto a reference pose (Kabsch; generalised Procrustes when
the reference is not given). This is the paper's "scaled to the same level in advance"
(Li et al. 2020, Section III-A), so training takes recorded elsewhere in the room, or
facing another way, still apply.

Pure functions: arrays in, arrays out. Positions in metres.
"""
from __future__ import annotations

import numpy as np

from . import kernels

__all__ = ["kabsch", "kabsch_svd", "normalise_frames"]


def kabsch(P: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Rotations ``R`` ``(N, 3, 3)`` minimising ``|P_t R_t - Q|`` for centred ``P`` ``(N, k, 3)``, ``Q`` ``(k, 3)``
    (compiled when :data:`streamfix.core.kernels.COMPILED`: every frame of every template is
    normalised with one, and the batched SVD was a large part of a streaming PCA fill's cost)."""
    H = np.swapaxes(P, 1, 2) @ Q                             # (N, 3, 3)
    return kernels.kabsch_rotations(H) if kernels.COMPILED else kabsch_svd(H)


def kabsch_svd(H: np.ndarray) -> np.ndarray:
    """The reference of :func:`kabsch`: ``U diag(1, 1, d) V^T`` from the SVD of each ``H_t = P_t^T Q``."""
    Ul, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Ul @ Vt))
    Ul[:, :, 2] *= d[:, None]
    return Ul @ Vt


def normalise_frames(Z: np.ndarray, n_pred: int, ref: np.ndarray | None, rotate: bool
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Express frames ``Z`` ``(N, k, 3)`` in the frame of their first ``n_pred`` (observed) joints.

    Subtracts the per-frame centroid of those joints and, with ``rotate``, rotates them
    onto ``ref`` ``(n_pred, 3)`` (Kabsch; generalised Procrustes if ``ref`` is None).
    Returns ``(local, centroid (N, 3), R (N, 3, 3), ref)``; room = local @ R^T + centroid.
    """
    cen = Z[:, :n_pred].mean(axis=1)
    L = Z - cen[:, None, :]
    if not rotate or n_pred < 3:
        R = np.broadcast_to(np.eye(3), (Z.shape[0], 3, 3))
        return L, cen, R, ref if ref is not None else L[:, :n_pred].mean(axis=0)
    if ref is None:
        sub = L[:: max(L.shape[0] // 150, 1), :n_pred]       # <= ~150 frames set the reference
        ref = sub[0]
        for _ in range(2):                                   # generalised Procrustes, 2 rounds
            ref = (sub @ kabsch(sub, ref)).mean(axis=0)
    R = kabsch(L[:, :n_pred], ref)
    return L @ R, cen, R, ref
