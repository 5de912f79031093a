"""Boundary correction of PCA gap fills (not in Li et al. 2020): the model's error on the
observed samples next to each gap, interpolated across the gap (:func:`residual_field`),
and the shrinking of a fill toward linear interpolation when that error is large against
the fill's own departure from linear (:func:`shrink_untrusted`). Used by
:func:`streamfix.core.pca_gapfill.fill_gaps`.

Pure functions: arrays in, arrays out. Positions ``(T, J, 3)`` metres, masks ``(T, J)``.
"""
from __future__ import annotations

import numpy as np

from .interpolate import continuity_baseline, neighbour_observations

__all__ = ["residual_field", "shrink_untrusted"]

_EPS = 1e-12


def residual_field(resid: np.ndarray, obs: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """Per filled sample, the probe residuals at the gap's two ends, linearly blended
    over the gap (one end known: held constant); zero elsewhere. ``(T, J, 3)``."""
    T_len = obs.shape[0]
    idx = np.arange(T_len)[:, None]
    prev, nxt = neighbour_observations(obs)
    jj = np.arange(obs.shape[1])[None, :]
    ep = np.where((prev >= 0)[..., None], resid[np.clip(prev, 0, T_len - 1), jj], np.nan)
    en = np.where((nxt < T_len)[..., None], resid[np.clip(nxt, 0, T_len - 1), jj], np.nan)
    w = ((idx - prev) / np.maximum(nxt - prev, 1))[..., None]
    both = np.isfinite(ep).all(-1) & np.isfinite(en).all(-1)
    corr = np.where(both[..., None], ep + w * (en - ep),
                    np.where(np.isfinite(ep), ep, np.where(np.isfinite(en), en, 0.0)))
    corr[~filled] = 0.0
    return np.nan_to_num(corr)


def shrink_untrusted(positions: np.ndarray, observed: np.ndarray, filled: np.ndarray, resid: np.ndarray,
                     kappa: float = 2.0) -> np.ndarray:
    """Shrink each gap's fill toward linear interpolation when the model missed the gap's ends.

    Not in the paper. Per joint and gap run: ``sigma`` = the larger norm (m) of the
    model's residuals ``e = x - x_hat`` at the observed samples just before/after the
    gap (``resid``, NaN where unknown), ``D`` = RMS distance (m) of the fill from the
    linear interpolation between the gap's ends (hold at a take's edge), and the fill
    becomes ``lin + s (fill - lin)`` with ``s = D^2 / (D^2 + (kappa sigma)^2)``: a model
    that cannot reproduce the samples next to the gap keeps only departures from linear
    much larger than its own error. Measured on Kinect takes (one limb blanked): a
    seated 3 s leg, whose partners are unrelated jittering joints, and a still arm had
    sigma as large as D or larger; arms moving inside the gap with their hand tip
    seen had sigma well below D (kept).
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    fil = np.asarray(filled, dtype=bool) & ~obs
    if not fil.any():
        return x.copy()
    T_len, J = obs.shape
    jj = np.arange(J)[None, :]
    base, prev, nxt = continuity_baseline(x, obs)
    hp, hn = prev >= 0, nxt < T_len
    pc, nc = np.clip(prev, 0, T_len - 1), np.clip(nxt, 0, T_len - 1)
    ep = np.where(hp, np.linalg.norm(resid[pc, jj], axis=2), np.nan)
    en = np.where(hn, np.linalg.norm(resid[nc, jj], axis=2), np.nan)
    sig = np.fmax(ep, en)                                    # NaN where neither end has a residual
    d = x - base
    d2 = np.where(fil & (hp | hn), (d ** 2).sum(axis=2), 0.0)
    # per run (joint, previous observed frame): mean |d|^2 over the run's filled samples
    key = (prev + 1) * J + jj                                # unique per (run, joint)
    tot = np.zeros((T_len + 1) * J)
    cnt = np.zeros((T_len + 1) * J)
    np.add.at(tot, key[fil], d2[fil])
    np.add.at(cnt, key[fil], 1.0)
    D2 = (tot / np.maximum(cnt, 1))[key]
    s = D2 / np.maximum(D2 + (kappa * np.nan_to_num(sig)) ** 2, _EPS)
    use = fil & (hp | hn) & np.isfinite(sig)
    out = x.copy()
    out[use] = (base + s[..., None] * d)[use]
    return out
