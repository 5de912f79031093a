"""Frame-rate conversion of position sequences (pure numpy).

A sensor running at ``dst_hz`` samples the motion at its own instants; it does not
average. So:

* an **integer** ratio ``src_hz / dst_hz = k`` (e.g. 120 -> 30 Hz, k = 4) takes every
  k-th frame exactly, frames 0, k, 2k, ... -- no smoothing, no interpolation;
* any other ratio (including upsampling) samples at ``t_i = i / dst_hz`` by linear
  interpolation between the two neighbouring source frames ``a = floor(u_i)``,
  ``a + 1`` with ``u_i = t_i * src_hz``. An interpolated sample is observed only if
  every source frame it draws on (non-zero weight) is observed.

The output covers ``[0, (T - 1) / src_hz]``: ``T' = floor((T - 1) * dst_hz / src_hz) + 1``.
"""
from __future__ import annotations

import numpy as np

from .points import finite_points

__all__ = ["resample_positions", "resample_plan", "resample_values"]

_RATIO_TOL = 1e-9


def resample_plan(n_frames: int, src_hz: float, dst_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source frames ``a``, ``b`` (T',) and weight ``w`` of ``b``: sample i = (1-w) x[a] + w x[b]."""
    if not (src_hz > 0 and dst_hz > 0 and np.isfinite(src_hz) and np.isfinite(dst_hz)):
        raise ValueError(f"rates must be positive numbers (Hz), got src_hz={src_hz}, dst_hz={dst_hz}")
    if n_frames <= 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty, np.zeros(0)
    ratio = src_hz / dst_hz
    k = round(ratio)
    if k >= 1 and abs(ratio - k) <= _RATIO_TOL * ratio:
        a = np.arange(0, n_frames, k, dtype=np.intp)
        return a, a, np.zeros(len(a))
    n_out = int(np.floor((n_frames - 1) * dst_hz / src_hz + 1e-9)) + 1
    u = np.arange(n_out) * ratio
    a = np.minimum(np.floor(u + 1e-9).astype(np.intp), n_frames - 1)
    w = np.clip(u - a, 0.0, 1.0)
    w[w < 1e-9] = 0.0
    b = np.minimum(a + 1, n_frames - 1)
    return a, b, w


def resample_values(values: np.ndarray, a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Apply a :func:`resample_plan` along axis 0 of ``values`` (any trailing shape)."""
    values = np.asarray(values)
    wb = w.reshape((-1,) + (1,) * (values.ndim - 1))
    out = values[a] * (1.0 - wb)
    has_b = w > 0
    out[has_b] += values[b[has_b]] * wb[has_b]
    return out


def resample_positions(
    positions: np.ndarray,
    src_hz: float,
    dst_hz: float,
    observed: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``(T, J, 3)`` positions (metres) from ``src_hz`` to ``dst_hz``.

    Returns ``(positions (T', J, 3), observed (T', J) bool)``; unobserved samples are NaN.
    ``observed`` defaults to "all coordinates finite".
    """
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3), got {positions.shape}")
    finite = finite_points(positions)
    observed = finite if observed is None else np.asarray(observed, dtype=bool) & finite
    if observed.shape != positions.shape[:2]:
        raise ValueError(f"observed must be {positions.shape[:2]}, got {observed.shape}")
    a, b, w = resample_plan(positions.shape[0], src_hz, dst_hz)
    obs = observed[a] & (observed[b] | (w == 0)[:, None])
    clean = np.where(observed[:, :, None], positions, 0.0)
    out = resample_values(clean, a, b, w)
    out[~obs] = np.nan
    return out, obs
