"""Gap interpolation along time, per joint coordinate: linear and cubic spline.

Input ``positions`` ``(T, J, 3)`` metres with missing samples NaN (or flagged by
``observed`` ``(T, J)`` False). Interior gaps are interpolated from the observed
samples of the same joint; leading/trailing gaps hold the nearest observation; a
joint never observed stays NaN. Both functions return ``(filled, filled_mask)`` where
``filled_mask`` ``(T, J)`` is True where a value was produced rather than observed.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dgtsv as _gtsv

from .points import finite_points

__all__ = ["interpolate_linear", "interpolate_spline", "cubic_spline_at", "spline_operator", "interpolate",
           "observed_mask", "neighbour_observations", "continuity_baseline", "missing_run_lengths", "run_labels"]


def observed_mask(positions: np.ndarray, observed: np.ndarray | None) -> np.ndarray:
    """``(T, J)`` (or ``(J,)``) bool: ``observed`` (None = all) and every coordinate finite."""
    finite = finite_points(positions)
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
    gaps = ~obs.all(axis=0)
    if not gaps.any():  # nothing to fill (most sensor windows): the same result without the gather
        return x.copy(), np.zeros_like(obs)
    if not gaps.all():  # joints are independent: only those with a gap are interpolated
        out, filled = x.copy(), np.zeros_like(obs)
        out[:, gaps], filled[:, gaps] = interpolate_linear(x[:, gaps], obs[:, gaps])
        return out, filled
    return _linear_rows(x, obs, None)


def _linear_rows(x: np.ndarray, obs: np.ndarray, rows: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`interpolate_linear` of ``x`` ``(T, J, 3)`` (``obs`` its observed mask) at the frames
    ``rows`` only (None: every frame): ``(values (R, J, 3), filled (R, J))``."""
    n, n_joints, _ = x.shape
    prev, nxt = neighbour_observations(obs)
    t = np.arange(n)
    x_r, obs_r = x, obs
    if rows is not None:
        prev, nxt, t, x_r, obs_r = prev[rows], nxt[rows], t[rows], x[rows], obs[rows]
    has_prev, has_next = prev >= 0, nxt < n
    p = np.clip(prev, 0, n - 1)
    q = np.clip(nxt, 0, n - 1)
    jj = np.arange(n_joints)[None, :]
    xp, xq = x[p, jj], x[q, jj]  # (R, J, 3)
    span = np.maximum(q - p, 1)
    w = np.clip((t[:, None] - p) / span, 0.0, 1.0)[..., None]
    interior = xp + w * (xq - xp)
    out = np.where((has_prev & has_next)[..., None], interior,
                   np.where(has_prev[..., None], xp, xq))
    never = ~(has_prev | has_next)
    out = np.where(obs_r[..., None], x_r, np.where(never[..., None], np.nan, out))
    filled = ~obs_r & ~never
    return out, filled


def interpolate_spline(
    positions: np.ndarray, observed: np.ndarray | None = None, frames: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Cubic-spline (not-a-knot) interpolation across interior gaps; edges hold nearest.

    One spline per set of joints observed on the same frames (3 coordinates at once; a
    whole-frame blackout gives every joint the same pattern, so one call serves them all);
    joints with fewer than 4 observations fall back to linear interpolation. ``frames``
    (indices, or a ``(T,)`` bool mask): only those frames are computed and returned, ``(len(frames), J, 3)`` and
    ``(len(frames), J)``, the values the whole call gives there (a window that needs its
    blackout frames alone does not interpolate every other gap).
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = observed_mask(x, observed)
    n = x.shape[0]
    t = np.arange(n, dtype=np.float64)
    if frames is None:
        rows = np.arange(n)
        out, filled = interpolate_linear(x, observed)
    else:
        frames = np.asarray(frames)
        rows = np.arange(n)[np.flatnonzero(frames) if frames.dtype == bool else frames.astype(np.intp)]
        out, filled = _linear_rows(x, obs, rows)
    at = t[rows]
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
        inside = ~pattern[rows] & (at > ts[0]) & (at < ts[-1])
        if inside.any():
            out[np.ix_(inside, members)] = cubic_spline_at(ts, x[pattern][:, members], at[inside])
    return out, filled


def cubic_spline_at(knots: np.ndarray, values: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """The not-a-knot cubic spline through ``values`` ``(n, ...)`` at ``knots`` ``(n,)``
    (increasing, n >= 4), evaluated at ``queries`` ``(m,)`` only: ``(m, ...)``.

    The same slopes as :class:`scipy.interpolate.CubicSpline` (the same tridiagonal system,
    solved by the same LAPACK ``gtsv``) and the same cubic on each interval, but only the
    intervals holding a query get coefficients. Why: a window's gaps are a few frames of
    600, and CubicSpline built all 600 intervals' coefficients for 75 series (a
    measurable share of an offline clean)."""
    x = np.asarray(knots, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    n = len(x)
    if n < 4:
        raise ValueError(f"a not-a-knot cubic spline needs at least 4 knots, got {n}")
    tail = y.shape[1:]
    y = y.reshape(n, -1)
    dx = np.diff(x)
    dxr = dx[:, None]
    slope = np.diff(y, axis=0) / dxr
    # the slopes s: dx[i] s[i-1] + 2 (dx[i-1] + dx[i]) s[i] + dx[i-1] s[i+1] = 3 (dx[i] m[i-1] + dx[i-1] m[i])
    diag = np.empty(n)
    upper = np.empty(n - 1)
    lower = np.empty(n - 1)
    rhs = np.empty_like(y)
    diag[1:-1] = 2 * (dx[:-1] + dx[1:])
    upper[1:] = dx[:-1]
    lower[:-1] = dx[1:]
    rhs[1:-1] = 3 * (dxr[1:] * slope[:-1] + dxr[:-1] * slope[1:])
    d = x[2] - x[0]  # not-a-knot: the third derivative continuous at the second and last-but-one knots
    diag[0], upper[0] = dx[1], d
    rhs[0] = ((dxr[0] + 2 * d) * dxr[1] * slope[0] + dxr[0] ** 2 * slope[1]) / d
    d = x[-1] - x[-3]
    diag[-1], lower[-1] = dx[-2], d
    rhs[-1] = (dxr[-1] ** 2 * slope[-2] + (2 * d + dxr[-1]) * dxr[-2] * slope[-1]) / d
    *_, s, info = _gtsv(lower, diag, upper, rhs, 1, 1, 1, 1)
    if info != 0:
        raise np.linalg.LinAlgError("cubic spline: singular slope system (repeated knots?)")
    q = np.asarray(queries, dtype=np.float64)
    i = np.clip(np.searchsorted(x, q, side="right") - 1, 0, n - 2)
    h = dxr[i]
    t = (s[i] + s[i + 1] - 2 * slope[i]) / h  # the Hermite cubic's coefficients, as CubicHermiteSpline's
    z = (q - x[i])[:, None]
    z2 = z * z
    # summed by ascending power as scipy's PPoly evaluates it (the same bits, not Horner's)
    out = y[i] + s[i] * z + ((slope[i] - s[i]) / h - t) * z2 + (t / h) * (z2 * z)
    return out.reshape((len(q),) + tail)


def spline_operator(present_rows: np.ndarray, missing_rows: np.ndarray) -> np.ndarray:
    """``(n_missing, n_present)`` matrix ``S``: the not-a-knot cubic spline through samples
    at frames ``present_rows`` evaluated at frames ``missing_rows`` is ``S @ values``
    (the spline is linear in its data), for scoring and applying it to many series at once."""
    p = np.asarray(present_rows, dtype=np.float64)
    q = np.asarray(missing_rows, dtype=np.float64)
    if len(p) < 4:
        raise ValueError(f"a cubic spline needs at least 4 present frames, got {len(p)}")
    return cubic_spline_at(p, np.eye(len(p)), q)


def interpolate(
    positions: np.ndarray, observed: np.ndarray | None = None, method: str = "linear"
) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch to ``interpolate_linear`` or ``interpolate_spline`` by name."""
    if method == "linear":
        return interpolate_linear(positions, observed)
    if method in ("spline", "cubic"):
        return interpolate_spline(positions, observed)
    raise ValueError(f"unknown interpolation method {method!r}; expected 'linear' or 'spline'")
