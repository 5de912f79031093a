"""Whole missing frames (blackouts) from a temporal PCA basis: Li et al. (2020), Eq. (9)-(16).

A run of frames with no observed joint is estimated inside a window around it from the
window's present rows and a temporal basis ``V`` trained on complete windows of the
training data (Eq. 9); ``r`` and the weights' ``tau`` (Eq. 13) are chosen on the training
windows. Not in the paper: the estimate is blended with a cubic spline through the
present rows by a two-fold cross-validated weight (:func:`_spline_blend_weight`); for
marker sets the spline is taken in co-rotating frames (:mod:`streamfix.core.corotating`),
and where no training window fits (a take shorter than the window) the spline fills alone.
Positions ``(T, J, 3)`` metres; NaN = not observed.
"""
from __future__ import annotations

import numpy as np

from .corotating import corotating_spline, neighbour_count
from .interpolate import spline_operator
from .pca_training import DEFAULT_ENERGY, _as_training, _observed_mask, _runs, _solve_sym, choose_rank
from .rigid_pairs import pair_distance_spread, rigid_neighbours

__all__ = ["eq16_estimate", "eq16_basis", "blackout_weights", "fill_blackouts"]

def eq16_estimate(B_present: np.ndarray, V_present: np.ndarray, V_missing: np.ndarray,
                  w: np.ndarray | None = None) -> np.ndarray:
    """Eq. (14)-(16): missing rows ``V^ (V~^T W V~)^-1 V~^T W B~``.

    ``B_present`` ``(j, c)`` present frames of ``c`` trajectories; ``V_present``
    ``(j, r)`` / ``V_missing`` ``(m - j, r)`` the basis rows of present / missing frames;
    ``w`` ``(j,)`` diagonal of ``W`` (ones if None). Returns ``(m - j, c)``.
    """
    Vp = np.asarray(V_present, dtype=np.float64)
    w = np.ones(Vp.shape[0]) if w is None else np.asarray(w, dtype=np.float64)
    VtW = Vp.T * w                                           # V~^T W
    alpha = _solve_sym(VtW @ Vp, VtW @ np.asarray(B_present, dtype=np.float64))  # Eq. (14)
    return np.asarray(V_missing) @ alpha                     # Eq. (12)/(16)


def eq16_basis(windows: np.ndarray, energy: float = DEFAULT_ENERGY, r_max: int | None = None) -> np.ndarray:
    """Eq. (9): temporal basis ``V`` ``(m, r+1)`` from training windows ``(K, m, c)``.

    Column 0 is the constant trajectory (each trajectory's offset); the rest are the
    leading eigenvectors of ``A A^T`` of the offset-free trajectories, ``r`` by
    :func:`choose_rank`.
    """
    A = np.asarray(windows, dtype=np.float64)
    m = A.shape[1]
    A = A - A.mean(axis=1, keepdims=True)
    lam, vecs = np.linalg.eigh(np.einsum("kmc,kpc->mp", A, A))  # A A^T, A = (A_1..A_K)
    r = choose_rank(lam, energy, min(r_max or m - 2, m - 2))
    const = np.full((m, 1), 1.0 / np.sqrt(m))
    V = np.hstack([const, vecs[:, ::-1][:, :r]])
    return V


def blackout_weights(missing_rows: np.ndarray, tau: float) -> np.ndarray:
    """``w_l = exp(-d_l / tau)`` for the present frames, ``d_l`` frames to nearest missing."""
    miss = np.asarray(missing_rows, dtype=bool)
    idx = np.arange(miss.size)
    mi = np.flatnonzero(miss)
    pos = np.searchsorted(mi, idx)
    left = np.abs(idx - mi[np.clip(pos - 1, 0, mi.size - 1)])
    right = np.abs(mi[np.clip(pos, 0, mi.size - 1)] - idx)
    d = np.minimum(left, right)[~miss]
    return np.exp(-(d - 1) / float(tau)) if np.isfinite(tau) else np.ones(d.size)


SPREAD_FRAMES = 1000
"""At most this many training frames (evenly spaced) measure the rigid partners of markers."""

_TAU_GRID = (4.0, 8.0, 16.0, 32.0, 64.0, np.inf)


def _choose_r_tau(V: np.ndarray, missing_rows: np.ndarray, windows: np.ndarray, max_cols: int = 3000,
                  rng_seed: int = 0, baseline: np.ndarray | None = None) -> tuple[int, float, float]:
    """Eq. (13) on the training samples: the number of basis columns ``r`` (at most
    ``V``'s, which the energy rule set) and the ``tau`` of ``W`` whose estimate of the
    removed rows from the reduced rows has the least squared error; then ``alpha``, the
    weight of that estimate against a cubic spline through the present rows (not in the
    paper) in the convex blend with the least squared error on the same samples. Why: a
    blackout of a few tenths of a second on smooth marker motion is spline territory
    (``eval --protocol blackout`` had the spline ahead of Eq. 16 at most levels), while
    longer ones carry motion only the temporal basis knows; the training windows tell which.
    ``baseline`` ``(K, n_missing, c)``: what the estimate is blended with on each training
    window, when not the room spline (:func:`_spline_blend_weight`)."""
    A = np.asarray(windows, dtype=np.float64)
    cols = np.moveaxis(A, 1, 0).reshape(A.shape[1], -1)      # (m, K*c) training trajectories
    if cols.shape[1] > max_cols:
        sel = np.random.default_rng(rng_seed).choice(cols.shape[1], max_cols, replace=False)
        cols = cols[:, sel]
    present = ~missing_rows
    r_all = V.shape[1]
    r_grid = np.unique(np.clip(np.round(np.geomspace(2, r_all, 8)).astype(int), 2, r_all))
    best, best_err = (r_all, np.inf), np.inf
    for tau in _TAU_GRID:
        w = blackout_weights(missing_rows, tau)
        for r in r_grid:
            pred = eq16_estimate(cols[present], V[present, :r], V[missing_rows, :r], w)
            err = float(np.mean((pred - cols[missing_rows]) ** 2))
            if err < best_err:
                best, best_err = (int(r), tau), err
    return best[0], best[1], _spline_blend_weight(A, missing_rows, best[0], best[1], V.shape[1] - 1, baseline)


def _spline_blend_weight(windows: np.ndarray, missing_rows: np.ndarray, r: int, tau: float, rank: int,
                         baseline: np.ndarray | None = None) -> float:
    """Weight of the Eq. (16) estimate against the cubic spline through the present rows
    (or ``baseline`` ``(K, n_missing, c)``, given per training window: the co-rotating
    spline): the convex blend with the least squared error on the training windows, two-fold
    cross-validated (a basis from every other window scores the rest, and back), since
    the basis scored on its own windows flatters itself. 1.0 = Eq. (16) alone; 0.0 = the
    spline alone, also when a single training window leaves nothing to cross-validate on."""
    A = np.asarray(windows, dtype=np.float64)
    present = ~np.asarray(missing_rows, dtype=bool)
    if int(present.sum()) < 4:
        return 1.0                                           # no spline to blend with
    if A.shape[0] < 2:
        return 0.0                                           # no second window to score a basis on

    rows = np.arange(len(missing_rows))
    S = spline_operator(rows[present], rows[missing_rows])
    w = blackout_weights(missing_rows, tau)
    num = den = 0.0
    for fold in (0, 1):
        fit, test = A[fold::2], A[1 - fold::2]
        if len(fit) == 0 or len(test) == 0:
            continue
        V = eq16_basis(fit, 1.0, rank)[:, :r]
        cols = np.moveaxis(test, 1, 0).reshape(test.shape[1], -1)
        pca = eq16_estimate(cols[present], V[present], V[missing_rows], w)
        if baseline is None:
            spline = S @ cols[present]
        else:
            spline = np.moveaxis(np.asarray(baseline)[1 - fold::2], 1, 0).reshape(len(S), -1)
        d = pca - spline
        num += float(np.sum(d * (cols[missing_rows] - spline)))
        den += float(np.sum(d * d))
    return float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 1.0


def fill_blackouts(
    positions: np.ndarray,
    observed: np.ndarray | None,
    training,
    *,
    blackout: np.ndarray | None = None,
    window: int = 200,
    max_fraction: float = 0.3,
    energy: float = 0.999,
    r_max: int | None = 60,
    bases: dict | None = None,
    corotating: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (9)-(16): fill runs of whole missing frames from a temporal PCA basis.

    ``blackout`` ``(T,)`` bool marks the frames to treat as missing whole (default:
    frames with no observed joint). Each run is estimated inside a window of
    ``max(window, run / max_fraction)`` frames around it (shifted inward at the take's
    ends, so a run at the very start or end is extrapolated). The present rows of the
    window must be complete (fill partial gaps first). ``bases`` caches ``V`` and
    ``tau`` per (window, template) between calls. ``corotating``: the estimate is blended
    with the spline in co-rotating frames (:func:`~streamfix.core.corotating.corotating_spline`,
    each marker's rigid partners taken from the training set) instead of the room spline;
    for marker sets. Returns ``(filled, filled_mask)``.
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = _observed_mask(x, observed)
    out = x.copy()
    out[~obs] = np.nan
    filled = np.zeros_like(obs)
    T_len, J, _ = x.shape
    if blackout is None:
        blackout = ~obs.any(axis=1)
    blackout = np.asarray(blackout, dtype=bool)
    runs = _runs(blackout)
    if not runs:
        return out, filled
    ts = _as_training(training, J)
    bases = {} if bases is None else bases
    for a, b in runs:
        L = b - a
        m = min(max(window, int(np.ceil(L / max_fraction))), T_len)
        if m - L < 4:
            continue                                         # nothing to anchor the fit
        s = int(np.clip(a - (m - L) // 2, 0, T_len - m))
        blk = np.arange(s, s + m)
        miss_rows = blackout[blk]
        present_ok = obs[blk][~miss_rows].all(axis=0)        # joints complete on present rows
        if not present_ok.any():
            continue
        key_v = ("V", m)
        if key_v not in bases:
            Aw = ts.windows(m, hop=max(m // 8, 1))
            bases[key_v] = (eq16_basis(Aw, energy, r_max) if len(Aw) else None, Aw)
        V, Aw = bases[key_v]
        n_present = int((~miss_rows).sum())
        has_model = V is not None and n_present > V.shape[1]
        if not has_model and n_present < 4:
            continue                                         # neither the basis nor a spline can fit
        if corotating and "spread" not in bases:
            frames = ts.frames[:: max(len(ts.frames) // SPREAD_FRAMES, 1)]
            bases["spread"] = pair_distance_spread(frames, np.isfinite(frames).all(axis=2))
        cols = x[blk].reshape(m, -1)
        okc = np.repeat(present_ok, 3)
        alpha, est = 0.0, 0.0
        if has_model:
            key_t = ("r_tau", m, miss_rows.tobytes(), corotating)
            if key_t not in bases:
                base = None
                if corotating:  # the blend weight is chosen against what it blends with
                    base = corotating_spline(Aw.reshape(len(Aw), m, J, 3), miss_rows,
                                             rigid_neighbours(bases["spread"], neighbour_count(J)))
                    base = base.reshape(len(Aw), int(miss_rows.sum()), -1)
                bases[key_t] = _choose_r_tau(V, miss_rows, Aw, baseline=base)
            r_cv, tau, alpha = bases[key_t]
            w = blackout_weights(miss_rows, tau)
            est = eq16_estimate(cols[~miss_rows][:, okc], V[~miss_rows, :r_cv], V[miss_rows, :r_cv], w)  # Eq. (16)
        # else no training window fits (a take shorter than the window, with the blackout in
        # it): the spline alone, not the linear interpolation left for what nothing filled
        if alpha < 1.0:
            # blended with the cubic spline by the weight the training windows chose
            rows = np.arange(m)
            S = spline_operator(rows[~miss_rows], rows[miss_rows])
            if corotating:
                ok = np.flatnonzero(present_ok)
                nb = rigid_neighbours(bases["spread"][np.ix_(ok, ok)], neighbour_count(len(ok)))
                spline = corotating_spline(x[blk][:, ok], miss_rows, nb, spline=S).reshape(len(S), -1)
            else:
                spline = S @ cols[~miss_rows][:, okc]
            est = alpha * est + (1.0 - alpha) * spline
        tgt = np.zeros((m, J), dtype=bool)
        tgt[miss_rows] = present_ok[None, :]
        tgt &= ~obs[blk]
        full = np.full((int(miss_rows.sum()), J * 3), np.nan)
        full[:, okc] = est
        full = full.reshape(-1, J, 3)
        sub_rows = blk[miss_rows]
        sel = tgt[miss_rows]
        out[sub_rows[:, None].repeat(J, 1)[sel], np.broadcast_to(np.arange(J), sel.shape)[sel]] = full[sel]
        filled[sub_rows[:, None].repeat(J, 1)[sel], np.broadcast_to(np.arange(J), sel.shape)[sel]] = True
    return out, filled

