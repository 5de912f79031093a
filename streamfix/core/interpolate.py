"""Gap interpolation along time, per joint coordinate: linear and cubic spline.

Input ``positions`` ``(T, J, 3)`` metres with missing samples NaN (or flagged by
``observed`` ``(T, J)`` False). Interior gaps are interpolated from the observed
samples of the same joint; leading/trailing gaps hold the nearest observation; a
joint never observed stays NaN. Both functions return ``(filled, filled_mask)`` where
``filled_mask`` ``(T, J)`` is True where a value was produced rather than observed.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

__all__ = ["interpolate_linear", "interpolate_spline", "spline_operator", "interpolate", "observed_mask",
           "neighbour_observations", "continuity_baseline", "missing_run_lengths", "run_labels"]


def observed_mask(positions: np.ndarray, observed: np.ndarray | None) -> np.ndarray:
    """``(T, J)`` (or ``(J,)``) bool: ``observed`` (None = all) and every coordinate finite."""
    f = np.isfinite(positions)
    # three slices: 3x cheaper than .all(axis=-1) over a length-3 axis (the streamed prior's latency path)
    finite = f[..., 0] & f[..., 1] & f[..., 2] if f.shape[-1] == 3 else f.all(axis=-1)
    if observed is None:
        return finite
    observed = np.asarray(observed, dtype=bool)
    if observed.shape != finite.shape:
        raise ValueError(f"observed must be {finite.shape}, got {observed.shape}")
    return observed & finite


def neighbour_observations(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each (t, j): index of the previous and next observed frame (-1 / T if none)."""
    n = obs.shape[0]
    idx = np.arange(n)[:, None]
    prev = np.maximum.accumulate(np.where(obs, idx, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(obs, idx, n)[::-1], axis=0)[::-1]
    return prev, nxt


def continuity_baseline(positions: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a gap "continues" as: hold from the previous observed sample, linear once the
    next one exists too (hold from the next at the take's start). Returns ``(base (T, J, 3),
    prev, nxt)`` with ``prev``/``nxt`` of :func:`neighbour_observations`; rows with no
    observation at all hold whatever ``positions`` has at frame 0 / T-1 (callers mask them)."""
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    T, J = obs.shape
    prev, nxt = neighbour_observations(obs)
    jj = np.arange(J)[None, :]
    hp, hn = prev >= 0, nxt < T
    xp, xn = x[np.clip(prev, 0, T - 1), jj], x[np.clip(nxt, 0, T - 1), jj]
    w = ((np.arange(T)[:, None] - prev) / np.maximum(nxt - prev, 1))[..., None]
    base = np.where((hp & hn)[..., None], xp + w * (xn - xp), np.where(hp[..., None], xp, xn))
    return base, prev, nxt


def missing_run_lengths(observed: np.ndarray) -> np.ndarray:
    """``(T, J)`` (or ``(T,)``) int: for each missing sample the length of the run of
    consecutive missing frames it sits in (0 where observed)."""
    obs = np.asarray(observed, dtype=bool)
    squeeze = obs.ndim == 1
    prev, nxt = neighbour_observations(obs[:, None] if squeeze else obs)
    run = np.where(obs[:, None] if squeeze else obs, 0, nxt - prev - 1)
    return run[:, 0] if squeeze else run


def run_labels(mask: np.ndarray) -> np.ndarray:
    """``(T, J)`` int: each run of consecutive True samples of one joint (``mask`` ``(T, J)``)
    numbered 1, 2, ... (joint by joint, in time order within a joint); 0 outside runs."""
    m = np.asarray(mask, dtype=bool)
    T, J = m.shape
    starts = m & ~np.concatenate([np.zeros((1, J), dtype=bool), m[:-1]], axis=0)
    return (np.cumsum(starts.T.ravel()).reshape(J, T) * m.T).T


def interpolate_linear(
    positions: np.ndarray, observed: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation across gaps (vectorised over frames and joints)."""
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3), got {x.shape}")
    obs = observed_mask(x, observed)
    if obs.all():  # nothing to fill (most sensor windows): the same result without the gather
        return x.copy(), np.zeros_like(obs)
    n, n_joints, _ = x.shape
    prev, nxt = neighbour_observations(obs)
    has_prev, has_next = prev >= 0, nxt < n
    p = np.clip(prev, 0, n - 1)
    q = np.clip(nxt, 0, n - 1)
    jj = np.arange(n_joints)[None, :]
    xp, xq = x[p, jj], x[q, jj]  # (T, J, 3)
    span = np.maximum(q - p, 1)
    w = np.clip((np.arange(n)[:, None] - p) / span, 0.0, 1.0)[..., None]
    interior = xp + w * (xq - xp)
    out = np.where((has_prev & has_next)[..., None], interior,
                   np.where(has_prev[..., None], xp, xq))
    never = ~(has_prev | has_next)
    out[never] = np.nan
    out[obs] = x[obs]
    filled = ~obs & ~never
    return out, filled


def interpolate_spline(
    positions: np.ndarray, observed: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Cubic-spline (not-a-knot) interpolation across interior gaps; edges hold nearest.

    One spline per set of joints observed on the same frames (3 coordinates at once; a
    whole-frame blackout gives every joint the same pattern, so one call serves them all);
    joints with fewer than 4 observations fall back to linear interpolation.
    """
    x = np.asarray(positions, dtype=np.float64)
    lin, filled = interpolate_linear(x, observed)
    obs = observed_mask(x, observed)
    n = x.shape[0]
    t = np.arange(n, dtype=np.float64)
    out = lin.copy()
    joints = np.flatnonzero(filled.any(axis=0) & (obs.sum(axis=0) >= 4))  # joints with gaps only
    if len(joints) == 0:
        return out, filled
    columns = obs[:, joints]
    # each joint's observation pattern as one byte string: equal patterns share a spline
    keys = np.packbits(columns, axis=0).T.copy().view(np.dtype((np.void, (n + 7) // 8))).ravel()
    _, first, group = np.unique(keys, return_index=True, return_inverse=True)
    for g, i in enumerate(first):
        pattern, members = columns[:, i], joints[group == g]
        ts = t[pattern]
        cs = CubicSpline(ts, x[pattern][:, members], axis=0, bc_type="not-a-knot")
        inside = ~pattern & (t > ts[0]) & (t < ts[-1])
        out[np.ix_(inside, members)] = cs(t[inside])
    return out, filled


def spline_operator(present_rows: np.ndarray, missing_rows: np.ndarray) -> np.ndarray:
    """``(n_missing, n_present)`` matrix ``S``: the not-a-knot cubic spline through samples
    at frames ``present_rows`` evaluated at frames ``missing_rows`` is ``S @ values``
    (the spline is linear in its data), for scoring and applying it to many series at once."""
    p = np.asarray(present_rows, dtype=np.float64)
    q = np.asarray(missing_rows, dtype=np.float64)
    if len(p) < 4:
        raise ValueError(f"a cubic spline needs at least 4 present frames, got {len(p)}")
    return CubicSpline(p, np.eye(len(p)), axis=0, bc_type="not-a-knot")(q)


def interpolate(
    positions: np.ndarray, observed: np.ndarray | None = None, method: str = "linear"
) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch to ``interpolate_linear`` or ``interpolate_spline`` by name."""
    if method == "linear":
        return interpolate_linear(positions, observed)
    if method in ("spline", "cubic"):
        return interpolate_spline(positions, observed)
    raise ValueError(f"unknown interpolation method {method!r}; expected 'linear' or 'spline'")
