"""Li et al. (2020) Eq. (4), (8), (16): vectorised code against a direct, unvectorised
reference written from the paper, and exact recovery of data that is exactly low rank."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import pca_gapfill as pg


def _top_right(M: np.ndarray, r: int) -> np.ndarray:
    """First r right singular vectors (= eigenvectors of M^T M), via SVD, not eigh."""
    return np.linalg.svd(M, full_matrices=False)[2][:r].T


def _procrustes(Ub: np.ndarray, Uref: np.ndarray) -> np.ndarray:
    W, _, Zt = np.linalg.svd(Ub.T @ Uref)
    return Ub @ W @ Zt


def ref_eq4(B0, A_list, A0_list, r):
    """Eq. (1)-(4) one piece at a time, sums written out."""
    U = _top_right(np.vstack(A_list), r)                     # Eq. (1) A^T A = U S U^T
    Uref = _top_right(np.vstack(A0_list), r)
    P = np.zeros((r, r))
    Q = np.zeros((r, r))
    for A, A0 in zip(A_list, A0_list):
        Ui = _procrustes(_top_right(A0, r), Uref)            # Eq. (1) individual eigenspace
        X = A0 @ Ui
        P += X.T @ X                                         # normal equations of Eq. (2)
        Q += X.T @ (A @ U)
    T = np.linalg.inv(P) @ Q                                 # Eq. (3)
    UB = _procrustes(_top_right(B0, r), Uref)
    return B0 @ UB @ T @ U.T                                 # Eq. (4)


def ref_eq8(B0, A_list, A0_list, r):
    """Eq. (5)-(8) with A = (A_1, ..., A_K) side by side."""
    left = lambda M: np.linalg.svd(M, full_matrices=False)[0][:, :r]  # eigvecs of M M^T
    V = left(np.hstack(A_list))                              # Eq. (5)
    Vref = left(np.hstack(A0_list))
    N = np.zeros((r, r))
    D = np.zeros((r, r))
    for A, A0 in zip(A_list, A0_list):
        Vi = _procrustes(left(A0), Vref)
        N += V.T @ A @ A0.T @ Vi                             # Eq. (7), first factor
        D += Vi.T @ A0 @ A0.T @ Vi                           # Eq. (7), second factor
    F = N @ np.linalg.inv(D)
    VB = _procrustes(left(B0), Vref)
    return V @ F @ VB.T @ B0                                 # Eq. (8)


def ref_eq16(B, missing_rows, V, w):
    """Eq. (13)-(16), one trajectory (column) at a time by weighted least squares."""
    present = ~missing_rows
    out = np.zeros((missing_rows.sum(), B.shape[1]))
    sw = np.sqrt(w)
    for c in range(B.shape[1]):
        alpha = np.linalg.lstsq(V[present] * sw[:, None], B[present, c] * sw, rcond=None)[0]  # Eq. (14)
        out[:, c] = V[missing_rows] @ alpha                  # Eq. (12)/(16)
    return out


@pytest.fixture
def small_case():
    rng = np.random.default_rng(7)
    n, K, m, r = 9, 4, 30, 3
    # noisy data with a clear rank-r structure (distinct eigenvalues)
    basis = rng.normal(size=(r, n)) * np.array([3.0, 2.0, 1.0])[:, None]
    A = [rng.normal(size=(m, r)) @ basis + 0.05 * rng.normal(size=(m, n)) for _ in range(K)]
    tmpl = np.ones((m, n), dtype=bool)
    tmpl[10:22, 2] = False
    tmpl[5:15, 6] = False
    A0 = [a * tmpl for a in A]
    B = rng.normal(size=(m, r)) @ basis + 0.05 * rng.normal(size=(m, n))
    return B, B * tmpl, A, A0, tmpl, r


def test_eq4_matches_unvectorised_reference(small_case):
    B, B0, A, A0, tmpl, r = small_case
    got = pg.eq4_estimate(B0, np.stack(A), np.stack(A0), r)
    np.testing.assert_allclose(got, ref_eq4(B0, A, A0, r), rtol=1e-7, atol=1e-9)


def test_eq8_matches_unvectorised_reference(small_case):
    B, B0, A, A0, tmpl, r = small_case
    got = pg.eq8_estimate(B0, np.stack(A), np.stack(A0), r)
    np.testing.assert_allclose(got, ref_eq8(B0, A, A0, r), rtol=1e-7, atol=1e-9)


def test_eq16_matches_unvectorised_reference():
    rng = np.random.default_rng(3)
    m, c, r = 40, 7, 5
    V = np.linalg.qr(rng.normal(size=(m, r)))[0]
    B = rng.normal(size=(m, c))
    miss = np.zeros(m, dtype=bool)
    miss[17:25] = True
    w = pg.blackout_weights(miss, 8.0)
    got = pg.eq16_estimate(B[~miss], V[~miss], V[miss], w)
    np.testing.assert_allclose(got, ref_eq16(B, miss, V, w), rtol=1e-8, atol=1e-10)
    # the weights are really used: uniform weights give a different answer
    assert not np.allclose(got, pg.eq16_estimate(B[~miss], V[~miss], V[miss], None))


def test_eq4_recovers_exactly_low_rank_data():
    rng = np.random.default_rng(11)
    n, r = 12, 4
    basis = rng.normal(size=(r, n))
    A = np.stack([rng.normal(size=(50, r)) @ basis for _ in range(3)])
    B = rng.normal(size=(40, r)) @ basis
    cols = np.ones(n, dtype=bool)
    cols[[1, 7]] = False                                     # two coordinates missing
    got = pg.eq4_estimate(B * cols, A, A * cols, r)
    np.testing.assert_allclose(got[:, ~cols], B[:, ~cols], atol=1e-8)


def test_eq16_recovers_trajectories_in_the_basis():
    rng = np.random.default_rng(5)
    m = 60
    t = np.arange(m)
    shapes = np.stack([np.sin(0.05 * t), np.cos(0.11 * t + 1.0), (t / m) ** 2], axis=1)  # (m, 3)
    windows = np.stack([shapes @ rng.normal(size=(3, 6)) + rng.normal(size=6) for _ in range(20)])
    V = pg.eq16_basis(windows, energy=0.999999)
    test = (windows[0] + windows[1])                         # a mix of training trajectories
    miss = np.zeros(m, dtype=bool)
    miss[25:35] = True
    est = pg.eq16_estimate(test[~miss], V[~miss], V[miss], pg.blackout_weights(miss, 16.0))
    np.testing.assert_allclose(est, test[miss], atol=1e-6)


def test_rank_rule():
    lam = np.array([50.0, 30.0, 15.0, 4.0, 1.0])
    assert pg.choose_rank(lam, 0.5) == 1
    assert pg.choose_rank(lam, 0.8) == 2
    assert pg.choose_rank(lam, 0.95) == 3
    assert pg.choose_rank(lam, 1.0) == 5
    assert pg.choose_rank(lam, 0.999, r_max=2) == 2
    assert pg.choose_rank(lam[::-1], 0.8) == 2             # order does not matter
    with pytest.raises(ValueError, match="energy"):
        pg.choose_rank(lam, 0.0)
