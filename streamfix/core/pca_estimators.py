"""Matrix-level PCA estimators of Li et al. (2020), Eq. (1)-(8): a complete motion matrix
from an incomplete one and complete training pieces.

Eq. (1)-(4): training pieces of one long sequence stacked vertically (:func:`eq4_estimate`);
Eq. (5)-(8): short pieces side by side, which is Eq. (4) on transposed matrices
(:func:`eq8_estimate`). Eigenbases are aligned by orthogonal Procrustes (an
eigen-decomposition fixes each eigenvector only up to sign and rotation among close
eigenvalues; see :mod:`streamfix.core.pca_gapfill` for the choices made). Matrices are
``m x n``: ``m`` frames, ``n = 3J`` coordinates; pure functions, arrays in and out.
"""
from __future__ import annotations

import numpy as np

from .pca_training import _solve_sym

__all__ = ["eq4_estimate", "eq8_estimate"]


def _top_eigvecs(G: np.ndarray, r: int) -> np.ndarray:
    """Leading ``r`` eigenvectors of symmetric ``G`` (``(..., n, n)`` -> ``(..., n, r)``)."""
    _, vecs = np.linalg.eigh(G)
    return vecs[..., ::-1][..., :r]


def _align(basis: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Rotate ``basis`` (``(..., n, r)``) within its span onto ``reference`` (Procrustes)."""
    M = np.swapaxes(basis, -1, -2) @ reference
    Wl, _, Zt = np.linalg.svd(M)
    return basis @ (Wl @ Zt)


def _eq4_from_grams(
    G: np.ndarray, C0: np.ndarray, G0: np.ndarray, GB0: np.ndarray, r: int, r0: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. (1)-(3) from Gram matrices; returns ``(U, U_B0, T)`` for Eq. (4).

    ``G`` ``(K, n, n)`` = ``A_i^T A_i``; ``C0`` ``(K, n, n)`` = ``A_i^(0)T A_i``;
    ``G0`` ``(K, n, n)`` = ``A_i^(0)T A_i^(0)``; ``GB0`` ``(n, n)`` = ``B^(0)T B^(0)``.
    ``r`` columns of ``U``; ``r0`` (default ``r``) columns of the incomplete bases.
    """
    r0 = r if r0 is None else r0
    U = _top_eigvecs(G.sum(axis=0), r)                       # Eq. (1): A^T A = U S U^T
    U_ref = _top_eigvecs(G0.sum(axis=0), r0)                 # pooled incomplete basis
    Ui0 = _align(_top_eigvecs(G0, r0), U_ref)                # Eq. (1): A_i^(0)T A_i^(0)
    UB0 = _align(_top_eigvecs(GB0, r0), U_ref)               # U_B^(0)
    Uit = np.swapaxes(Ui0, -1, -2)
    P = (Uit @ G0 @ Ui0).sum(axis=0)                         # sum U_i0^T A_i0^T A_i0 U_i0
    Q = (Uit @ C0 @ U).sum(axis=0)                           # sum U_i0^T A_i0^T A_i U
    T = _solve_sym(P, Q)                                     # Eq. (3) (normal equations of Eq. 2)
    return U, UB0, T


# --------------------------------------------------------------------------- matrix level
def eq4_estimate(B0: np.ndarray, A: np.ndarray, A0: np.ndarray, r: int) -> np.ndarray:
    """Eq. (4): ``B* = B^(0) U_B^(0) T U^T`` (estimate of the complete ``B``, ``m x n``).

    ``B0`` ``(m, n)`` incomplete (template entries zero); ``A`` ``(K, m_i, n)`` complete
    training pieces of one long sequence; ``A0`` the same with the template applied.
    """
    B0 = np.asarray(B0, dtype=np.float64)
    A = np.asarray(A, dtype=np.float64)
    A0 = np.asarray(A0, dtype=np.float64)
    At, A0t = np.swapaxes(A, -1, -2), np.swapaxes(A0, -1, -2)
    U, UB0, T = _eq4_from_grams(At @ A, A0t @ A, A0t @ A0, B0.T @ B0, r)
    return B0 @ UB0 @ T @ U.T                                # Eq. (4)


def eq8_estimate(B0: np.ndarray, A: np.ndarray, A0: np.ndarray, r: int) -> np.ndarray:
    """Eq. (8): ``B* = V F V_B^(0)T B^(0)``; training pieces side by side, ``A = (A_1..A_K)``.

    Shapes as :func:`eq4_estimate`, but every piece has the same ``m`` frames as ``B``
    (``V`` is the ``m x r`` temporal eigenbasis of ``A A^T``, Eq. 5). With
    ``P_i = A_i^(0)T V_i^(0)``, Eq. (7) is ``F^T = (sum P_i^T P_i)^-1 sum P_i^T A_i^T V``,
    i.e. Eq. (3) on transposed matrices, so Eq. (8) is Eq. (4) on ``B^T``.
    """
    A = np.asarray(A, dtype=np.float64)
    A0 = np.asarray(A0, dtype=np.float64)
    B0 = np.asarray(B0, dtype=np.float64)
    if A.shape[1] != B0.shape[0]:
        raise ValueError(f"Eq. (8) needs training pieces of B's {B0.shape[0]} frames, got {A.shape[1]}")
    # Eq. (5)-(7) via Grams over the frame axis: A_i A_i^T, A_i^(0) A_i^T, A_i^(0) A_i^(0)T.
    V, VB0, Ft = _eq4_from_grams(A @ np.swapaxes(A, -1, -2), A0 @ np.swapaxes(A, -1, -2),
                                 A0 @ np.swapaxes(A0, -1, -2), B0 @ B0.T, r)
    return V @ Ft.T @ VB0.T @ B0                             # Eq. (8)
