"""Undo left/right swaps: a sensor that briefly gives the left leg the right leg's joints.

Why: depth sensors lose track of which limb is which when limbs pass each other or one
hides the other (on UI-PRMD about one swap every 10 s per leg pair, lasting 5-17 frames;
docs/SENSOR_ERRORS.md). Every joint of the limb then sits tens of centimetres from where
it was a frame before. A smoother spreads that error out; it does not remove it.

The test, per frame ``t`` and per mirror pair of limbs ``(A, B)`` (joints and their
mirror images, :func:`streamfix.limbs.limb_groups`):

* a reference trajectory ``m`` = running median over ``window_s`` (longer than twice the
  longest swap, so a swap is a minority of every median's samples);
* ``keep(t)`` = mean distance of A's and B's joints to ``m``; ``swap(t)`` = the same
  with A and B exchanged;
* the frame is swapped back where ``swap < ratio * keep`` and ``keep > min_offset_m``:
  the exchanged assignment explains the frame much better, and the current one is
  grossly off (a leg crossing the other moves smoothly and keeps ``keep`` small).

Arrays: positions ``(T, J, 3)`` metres (NaN = missing, never swapped).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filters import odd_window, running_median

__all__ = ["SwapConfig", "undo_limb_swaps"]


@dataclass(frozen=True)
class SwapConfig:
    """Knobs of :func:`undo_limb_swaps` (seconds, metres)."""

    window_s: float = 1.0
    min_offset_m: float = 0.05
    ratio: float = 0.5


def undo_limb_swaps(
    positions: np.ndarray,
    pairs: list[tuple[np.ndarray, np.ndarray]],
    rate_hz: float,
    cfg: SwapConfig = SwapConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """Positions with swapped limb pairs exchanged back, and the ``(T, J)`` mask of the
    joint-frames that were exchanged. ``pairs``: ``(A, B)`` index arrays of equal length,
    ``B[i]`` the mirror image of ``A[i]``."""
    x = np.asarray(positions, dtype=np.float64)
    out = x.copy()
    mask = np.zeros(x.shape[:2], dtype=bool)
    if x.shape[0] < 3 or not pairs:
        return out, mask
    ref = running_median(x, odd_window(cfg.window_s, rate_hz))
    for a, b in pairs:
        both = np.concatenate([a, b])
        mirrored = np.concatenate([b, a])
        keep = np.linalg.norm(x[:, both] - ref[:, both], axis=2)  # (T, n)
        swap = np.linalg.norm(x[:, mirrored] - ref[:, both], axis=2)
        ok = np.isfinite(keep) & np.isfinite(swap)
        n = ok.sum(axis=1)
        k = np.where(ok, keep, 0.0).sum(axis=1) / np.maximum(n, 1)
        s = np.where(ok, swap, 0.0).sum(axis=1) / np.maximum(n, 1)
        flip = (n == len(both)) & (k > cfg.min_offset_m) & (s < cfg.ratio * k)
        if flip.any():
            rows = np.flatnonzero(flip)
            out[rows[:, None], both[None, :]] = x[rows[:, None], mirrored[None, :]]
            mask[rows[:, None], both[None, :]] = True
    return out, mask
