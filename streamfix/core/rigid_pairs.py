"""Rigid marker pairs: which markers keep their distance, and keeping fills inside it.

Not in the paper. Markers on one body segment keep their distance; a gap fill that
stretches such a pair is implausible. :func:`estimate_rigid_pairs` finds the pairs
whose distance varies least where both are observed (:func:`pair_distance_spread`; per
marker, :func:`rigid_neighbours`), :func:`pair_distance_ranges`
their observed range, :func:`project_pair_distances` moves filled markers back inside
it, :func:`pair_distance_plausibility` scores a fill. Positions ``(T, J, 3)`` metres.
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .pca_training import _observed_mask
from .points import finite_points, point_norms

__all__ = ["pair_distances", "pair_distances_numpy", "pair_distance_spread", "estimate_rigid_pairs", "rigid_neighbours",
           "pair_distance_ranges", "project_pair_distances", "pair_distance_plausibility"]


SPREAD_CHUNK_FRAMES = 4096
"""Frames per chunk of :func:`pair_distance_spread`: 4096 frames of 41 markers' 820 pairs
hold 80 MB of differences; a 10-minute take at once held 4 GB."""


def pair_distances_numpy(x: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """Distance (m) of each marker pair ``(ia[p], ib[p])`` in every frame of ``x`` ``(T, J, 3)``,
    a NaN coordinate difference counting as 0: ``(T, P)``, stored pair by pair (its transpose is
    C-contiguous; numpy's sums over frames depend on that order). The numpy reference of
    :func:`streamfix.core.kernels.pair_distances`."""
    xt = np.asarray(x, dtype=np.float64).transpose(1, 0, 2)   # (J, T, 3)
    return point_norms(np.nan_to_num(xt[ia] - xt[ib])).T


def pair_distances(x: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """:func:`pair_distances_numpy`, compiled when :data:`streamfix.core.kernels.COMPILED` (same values)."""
    return (kernels.pair_distances if kernels.COMPILED else pair_distances_numpy)(x, ia, ib)


def pair_distance_spread(positions: np.ndarray, observed: np.ndarray | None = None,
                         min_common: float = 0.25) -> np.ndarray:
    """``(J, J)`` standard deviation (m) of each marker pair's distance over the frames where
    both are observed; ``inf`` on the diagonal and for pairs seen together in fewer than
    ``min_common`` of the frames (a fraction, or a frame count if > 1): a pair seen together
    only while the body stood still looks rigid without being so."""
    x = np.asarray(positions, dtype=np.float64)
    obs = _observed_mask(x, observed)
    T_len, J, _ = x.shape
    need = min_common * T_len if min_common <= 1 else min_common
    ia, ib = np.triu_indices(J, 1)
    # one pass over frame chunks (the (T, P, 3) differences of a long take would not fit in
    # memory): sums of the distances less a per-pair shift, the first chunk's mean, which
    # keeps the variance's two sums from cancelling
    cnt, s1, s2 = np.zeros(len(ia)), np.zeros(len(ia)), np.zeros(len(ia))
    shift = None
    for a in range(0, T_len, SPREAD_CHUNK_FRAMES):
        c = slice(a, a + SPREAD_CHUNK_FRAMES)
        both = obs[c, ia] & obs[c, ib]                       # (t, P)
        d = pair_distances(x[c], ia, ib)
        n = both.sum(axis=0)
        if shift is None:
            shift = (d * both).sum(axis=0) / np.maximum(n, 1)
        e = (d - shift) * both
        cnt += n
        s1 += e.sum(axis=0)
        s2 += (e * e).sum(axis=0)
    m1 = s1 / np.maximum(cnt, 1)
    var = np.maximum(s2 / np.maximum(cnt, 1) - m1 * m1, 0.0)
    spread = np.full((J, J), np.inf)
    spread[ia, ib] = spread[ib, ia] = np.where(cnt >= max(need, 2), np.sqrt(var), np.inf)
    return spread


def estimate_rigid_pairs(positions: np.ndarray, observed: np.ndarray | None = None, k: int = 60,
                         min_common: float = 0.25) -> np.ndarray:
    """The ``k`` marker pairs whose distance varies least (:func:`pair_distance_spread`).
    Returns ``(k, 2)`` int pairs, most rigid first."""
    spread = pair_distance_spread(positions, observed, min_common)
    ia, ib = np.triu_indices(spread.shape[0], 1)
    score = spread[ia, ib]
    order = np.argsort(score, kind="stable")[: min(k, int(np.isfinite(score).sum()))]
    return np.stack([ia[order], ib[order]], axis=1).astype(np.intp)


def rigid_neighbours(spread: np.ndarray, k: int) -> np.ndarray:
    """``(J, k)`` indices: per marker, the ``k`` others whose distance to it varies least
    (``spread`` from :func:`pair_distance_spread`; ties in index order)."""
    s = np.asarray(spread, dtype=np.float64)
    k = int(min(max(k, 0), s.shape[0] - 1))
    s = s.copy()
    np.fill_diagonal(s, np.inf)
    return np.argsort(s, axis=1, kind="stable")[:, :k]


def pair_distance_ranges(positions: np.ndarray, observed: np.ndarray, pairs: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """``(min, max)`` distance (m) of each pair over frames where both markers are observed."""
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    a, b = np.asarray(pairs, dtype=np.intp).reshape(-1, 2).T
    d = point_norms(x[:, a] - x[:, b])
    both = obs[:, a] & obs[:, b]
    return np.min(np.where(both, d, np.inf), axis=0), np.max(np.where(both, d, -np.inf), axis=0)


def project_pair_distances(positions: np.ndarray, movable: np.ndarray, pairs: np.ndarray,
                           dmin: np.ndarray, dmax: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Move only ``movable`` ``(T, J)`` samples so each pair's distance enters ``[dmin, dmax]``.

    Jacobi projection (vectorised over frames and pairs): each out-of-range pair
    asks its movable end(s) to close the excess along the pair's direction; a
    sample's requests are averaged. Loops over iterations only. Observed samples
    never move. Returns new positions ``(T, J, 3)``.
    """
    x = np.asarray(positions, dtype=np.float64).copy()
    mov = np.asarray(movable, dtype=bool) & finite_points(x)
    a, b = np.asarray(pairs, dtype=np.intp).reshape(-1, 2).T
    if a.size == 0 or not mov.any():
        return x
    lo = dmin + 0.02 * (dmax - dmin)                         # aim a little inside the range
    hi = dmax - 0.02 * (dmax - dmin)
    rows = np.flatnonzero(mov.any(axis=1))                  # frames nothing can move in stay as they are
    xs, ms = x[rows], mov[rows]
    ma, mb = ms[:, a].astype(np.float64), ms[:, b].astype(np.float64)
    share = ma + mb
    wa = np.divide(ma, share, out=np.zeros_like(ma), where=share > 0)[..., None]
    wb = np.divide(mb, share, out=np.zeros_like(mb), where=share > 0)[..., None]
    J = x.shape[1]
    # pair -> marker incidence: a sample's requests summed by one matrix product (np.add.at's
    # unbuffered scatter was two thirds of a marker take's gap fill)
    P = len(a)
    inc = np.zeros((2 * P, J))                               # rows: pairs' a ends, then b ends
    inc[np.arange(P), a] = 1.0
    inc[P + np.arange(P), b] = 1.0
    for _ in range(iterations):
        v = xs[:, b] - xs[:, a]                              # (t, P, 3)
        L = point_norms(v)
        tgt = np.clip(L, lo, hi)
        bad = np.isfinite(L) & (L > 0) & ((L < lo) | (L > hi))
        if not bad.any():
            break
        step = np.where(bad, (L - tgt) / np.where(L > 0, L, 1.0), 0.0)[..., None] * np.nan_to_num(v)
        t = len(xs)
        req = np.concatenate([(wa * step).transpose(0, 2, 1), -(wb * step).transpose(0, 2, 1)], axis=2)
        acc = (req.reshape(t * 3, -1) @ inc).reshape(t, 3, J).transpose(0, 2, 1)      # (t, J, 3)
        cnt = np.concatenate([(wa[..., 0] > 0) & bad, (wb[..., 0] > 0) & bad], axis=1) @ inc
        xs += acc / np.maximum(cnt, 1)[..., None]
    x[rows] = xs
    return x


def pair_distance_plausibility(positions: np.ndarray, observed: np.ndarray, filled: np.ndarray,
                               pairs: np.ndarray, tol_m: float = 0.0) -> float:
    """Fraction of filled samples whose rigid-pair distances lie in the observed range.

    For each pair, the range ``[min, max]`` of its distance over frames where both
    markers were observed (widened by ``tol_m``); a filled sample (t, j) is plausible
    when every pair involving ``j`` whose other marker exists at ``t`` stays in range.
    Samples in no pair are not counted. Returns a fraction in [0, 1] (nan if none).
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    fil = np.asarray(filled, dtype=bool)
    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    a, b = pairs[:, 0], pairs[:, 1]
    d = point_norms(x[:, a] - x[:, b])           # (T, P)
    both = obs[:, a] & obs[:, b]
    dmin = np.nanmin(np.where(both, d, np.inf), axis=0) - tol_m
    dmax = np.nanmax(np.where(both, d, -np.inf), axis=0) + tol_m
    inside = (d >= dmin) & (d <= dmax)
    exists = np.isfinite(d)
    T_len, J = obs.shape
    bad = np.zeros((T_len, J), dtype=bool)
    counted = np.zeros((T_len, J), dtype=bool)
    for side, other in ((a, b), (b, a)):                     # loop over 2 sides, vectorised over pairs
        rel = fil[:, side] & exists
        c = np.zeros((T_len, J), dtype=np.int64)
        np.add.at(c.T, side, rel.T)
        counted |= c > 0
        bb = np.zeros((T_len, J), dtype=np.int64)
        np.add.at(bb.T, side, (rel & ~inside).T)
        bad |= bb > 0
    n = int((counted & fil).sum())
    if n == 0:
        return float("nan")
    return float(((counted & fil) & ~bad).sum() / n)

