"""Medians of NaN-padded arrays, fast on the small arrays the per-window stages use.

``numpy.nanmedian`` goes through masked arrays when the reduced axis is short (under 600
samples: every window here), which is slow on a window's arrays; one sort with NaN
sorting last and the two middle elements of each column's finite run is much cheaper
and gives the same values. Arrays in, arrays out.
"""
from __future__ import annotations

import numpy as np

__all__ = ["nanmedian"]


def nanmedian(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """Median along ``axis`` ignoring NaN (NaN where a slice has no finite value), as
    :func:`numpy.nanmedian`."""
    v = np.sort(np.moveaxis(np.asarray(values, dtype=np.float64), axis, 0), axis=0)  # NaN last
    n = np.isfinite(v).sum(axis=0)
    last = max(v.shape[0] - 1, 0)
    if v.shape[0] == 0:
        return np.full(v.shape[1:], np.nan)
    lo = np.take_along_axis(v, np.minimum(np.maximum(n - 1, 0) // 2, last)[None], axis=0)[0]
    hi = np.take_along_axis(v, np.minimum(n // 2, last)[None], axis=0)[0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)
