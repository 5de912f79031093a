"""Gap filling with Eq. (5)-(8) of Li et al. 2020 at the positions level: the training
set as short pieces side by side, one template per gap (the missing frames of the gap's
joint in a block around it). Kept as derived and selectable (``fill_gaps(...,
layout="pieces")``), not the default: on the CMU takes it fills worse than the local
templates of :func:`streamfix.core.pca_gapfill.fill_gaps` (see that module).

Pure function: arrays in, arrays out. Positions ``(T, J, 3)`` metres.
"""
from __future__ import annotations

import numpy as np

from .pca_estimators import _eq4_from_grams
from .pca_training import _runs, choose_rank

__all__ = ["fill_gaps_pieces"]


def fill_gaps_pieces(x, obs, ts, rows, *, energy, r_max, window):
    """Eq. (5)-(8) on a block of ``max(window, 3 x gap)`` frames centred on each gap run.

    The template of Eq. (8) is the set of missing frames of the gap's joint in the
    block; every column of every block-length training piece gets that template
    (``A_i^(0)``), so ``F`` is learned for exactly that gap shape. ``V_B^(0)`` comes
    from all of the block's trajectories complete on the present frames, with the
    template applied.
    Trajectories are offset by their mean over the present frames (same rule for the
    training pieces). Joints absent from the whole block are left to the caller.
    """
    T_len, J, _ = x.shape
    out = x.copy()
    out[~obs] = np.nan
    filled = np.zeros_like(obs)
    cache: dict = {}
    need = ~obs & (np.arange(T_len)[:, None] >= 0)
    need[np.setdiff1d(np.arange(T_len), rows)] = False
    for j in np.flatnonzero(need.any(axis=0)):               # loop over gap runs, not frames
        for a, b in _runs(need[:, j]):
            m = min(max(window, 3 * (b - a)), T_len)
            s = int(np.clip(a - (m - (b - a)) // 2, 0, T_len - m))
            blk = slice(s, s + m)
            ob = obs[blk]
            present = ob[:, j]
            if present.sum() < 4:
                continue
            if m not in cache:
                cache[m] = ts.windows(m)                     # (K, m, n_tr) complete pieces
            A = cache[m]
            if A.shape[0] == 0:
                continue
            w = present.astype(np.float64)[:, None]
            cnt = present.sum()
            Ac = A - (A * w).sum(axis=1, keepdims=True) / cnt       # offsets from present rows
            A0 = Ac * w                                              # the template
            cols_ok = ob[present].all(axis=0)                        # joints complete on present rows
            Bb = x[blk][:, cols_ok].reshape(m, -1)
            muB = (Bb * w).sum(axis=0, where=np.isfinite(Bb)) / cnt
            B0 = np.where(w > 0, Bb - muB, 0.0)
            lam = np.linalg.eigvalsh(np.einsum("kmc,kpc->mp", Ac, Ac))
            r = min(choose_rank(lam, energy, r_max), int(cnt) - 1)
            At, A0t = np.swapaxes(Ac, 1, 2), np.swapaxes(A0, 1, 2)
            V, VB0, Ft = _eq4_from_grams(Ac @ At, A0 @ At, A0 @ A0t, B0 @ B0.T, r)  # Eq. (5)-(7)
            c = int(np.searchsorted(np.flatnonzero(cols_ok), j))
            est = V @ Ft.T @ VB0.T @ B0[:, 3 * c:3 * c + 3] + muB[3 * c:3 * c + 3]  # Eq. (8)
            rr = np.arange(s, s + m)[~present]
            out[rr, j] = est[~present]
            filled[rr, j] = True
    filled &= ~obs
    return out, filled
