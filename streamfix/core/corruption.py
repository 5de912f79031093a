"""Synthetic corruption of clean motion (Yang et al. 2019, Section IV-B protocol).

* :func:`add_noise` -- "random noise is added to a fraction of entities in the
  ground-truth skeleton matrix": the skeleton matrix ``D`` is ``3T x S`` (Eq. 1), so an
  *entry* is one scalar coordinate of one joint in one frame. Exactly
  ``round(m * 3 T S)`` entries, drawn without replacement, get noise uniform in
  ``[-0.25, 0.25]`` m (the paper's [-25, 25] cm).
* :func:`gap_mask` -- the gap variant: runs of 10-60 frames of one random joint are
  made missing until exactly ``round(m * T S)`` joint-frames are missing.

Pure functions, seeded through a ``numpy.random.Generator``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["add_noise", "gap_mask", "apply_gaps"]


def add_noise(
    positions: np.ndarray,
    fraction: float,
    rng: np.random.Generator,
    amplitude: float = 0.25,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrupt a fraction of scalar entries of ``(T, J, 3)`` with U[-amplitude, amplitude] m.

    Returns ``(corrupted, mask)`` with ``mask`` ``(T, J, 3)`` bool True on corrupted entries.
    """
    x = np.asarray(positions, dtype=np.float64)
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must be in [0, 1], got {fraction}")
    n = x.size
    k = int(round(fraction * n))
    flat = np.zeros(n, dtype=bool)
    flat[rng.choice(n, size=k, replace=False)] = True
    mask = flat.reshape(x.shape)
    out = x.copy()
    out[mask] += rng.uniform(-amplitude, amplitude, size=k)
    return out, mask


def gap_mask(
    n_frames: int,
    n_joints: int,
    fraction: float,
    rng: np.random.Generator,
    min_len: int = 10,
    max_len: int = 60,
) -> np.ndarray:
    """``(T, J)`` bool, True = missing: random joint runs of ``min_len..max_len`` frames.

    Runs are drawn (joint, start, length uniform in [min_len, max_len]) until
    ``round(fraction * T * J)`` joint-frames are missing; the last run is trimmed so the
    count is exact.
    """
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction must be in [0, 1), got {fraction}")
    target = int(round(fraction * n_frames * n_joints))
    missing = np.zeros((n_frames, n_joints), dtype=bool)
    count = 0
    while count < target:  # loops over runs, not frames
        j = int(rng.integers(n_joints))
        length = int(rng.integers(min_len, max_len + 1))
        start = int(rng.integers(0, max(n_frames - length, 0) + 1))
        stop = min(start + length, n_frames)
        new = np.flatnonzero(~missing[start:stop, j]) + start
        new = new[: target - count]
        missing[new, j] = True
        count += new.size
    return missing


def apply_gaps(positions: np.ndarray, missing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions with the ``missing`` joint-frames set to NaN, and the observed mask."""
    out = np.asarray(positions, dtype=np.float64).copy()
    missing = np.asarray(missing, dtype=bool)
    out[missing] = np.nan
    return out, ~missing
