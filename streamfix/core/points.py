"""Per-point reductions over the xyz axis of ``(..., 3)`` arrays: lengths, all/any, finite.

Why not ``np.linalg.norm(v, axis=-1)`` or ``mask.all(axis=-1)``: numpy reduces a 3-long
last axis element by element through its generic reduction loop, which on a window's
``(T, J, 3)`` arrays costs several times as much as three whole-array operations on the x, y
and z planes (measured for a norm of a window's points). These helpers give the
same values (the norm bit for bit: ((x^2 + y^2) + z^2), the order numpy sums in) and are
what the window cleaner and the streaming engine use on points.
"""
from __future__ import annotations

import numpy as np

__all__ = ["point_norms", "point_dots", "all_xyz", "any_xyz", "finite_points"]


def _check_xyz(a: np.ndarray) -> None:
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"expected points (..., 3), got shape {a.shape}")


def point_norms(v: np.ndarray) -> np.ndarray:
    """Euclidean length of each point (or vector) ``v`` ``(..., 3)`` -> ``(...)``, in v's units;
    the values of ``np.linalg.norm(v, axis=-1)``. NaN where a coordinate is NaN."""
    v = np.asarray(v, dtype=np.float64)
    _check_xyz(v)
    sq = v[..., 0] * v[..., 0]
    sq += v[..., 1] * v[..., 1]
    sq += v[..., 2] * v[..., 2]
    return np.sqrt(sq, out=sq) if np.ndim(sq) else np.sqrt(sq)  # one point: a scalar


def point_dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product of each pair of vectors ``a``, ``b`` ``(..., 3)`` (broadcast) -> ``(...)``;
    the values of ``(a * b).sum(axis=-1)``."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    _check_xyz(a)
    _check_xyz(b)
    out = a[..., 0] * b[..., 0]
    out = out + a[..., 1] * b[..., 1]
    out += a[..., 2] * b[..., 2]
    return out


def all_xyz(mask: np.ndarray) -> np.ndarray:
    """``mask`` ``(..., 3)`` bool -> ``(...)``: True where all three are (``mask.all(axis=-1)``)."""
    m = np.asarray(mask)
    _check_xyz(m)
    return m[..., 0] & m[..., 1] & m[..., 2]


def any_xyz(mask: np.ndarray) -> np.ndarray:
    """``mask`` ``(..., 3)`` bool -> ``(...)``: True where any of the three is (``mask.any(axis=-1)``)."""
    m = np.asarray(mask)
    _check_xyz(m)
    return m[..., 0] | m[..., 1] | m[..., 2]


def finite_points(x: np.ndarray) -> np.ndarray:
    """``x`` ``(..., 3)`` -> ``(...)`` bool: True where the point has three finite coordinates
    (``np.isfinite(x).all(axis=-1)``)."""
    return all_xyz(np.isfinite(x))
