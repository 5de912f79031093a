"""Undo left/right swaps: a sensor that briefly gives the left leg the right leg's joints.

Why: depth sensors lose track of which limb is which when limbs pass each other or one
hides the other (on UI-PRMD about one swap every 10 s per leg pair, lasting 5-17 frames;
docs/SENSOR_ERRORS.md). Every joint of the limb then sits tens of centimetres from where
it was a frame before. A smoother spreads that error out; it does not remove it.

The test, per mirror pair of limbs ``(A, B)`` (joints and their mirror images,
:func:`streamfix.limbs.limb_groups`), looks for the *moments* a swap starts and ends:

* each joint is predicted at constant velocity from the two frames before,
  ``p(t) = 2 x(t-1) - x(t-2)`` (a walking foot moves 10+ cm a frame; a running median
  cannot follow it, a prediction can; the second frame, with one frame before it, at
  ``x(0)``);
* ``keep(t)`` = mean distance of A's and B's joints to their own predictions,
  ``cross(t)`` = the same with A and B exchanged; frame ``t`` *toggles* the labelling
  where ``cross < ratio * keep`` and ``keep > min_offset_m`` (the exchanged labelling
  continues the motion much better, and the current one jumps grossly);
* a frame is swapped where an odd number of toggles came before it (a cumulative sum,
  no loop over frames); a swapped stretch longer than ``max_swap_s`` is not believed
  (a missed toggle would otherwise swap everything after it) and is left alone.

Arrays: positions ``(T, J, 3)`` metres (NaN = missing, never swapped).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .points import point_norms


__all__ = ["SwapConfig", "undo_limb_swaps"]


@dataclass(frozen=True)
class SwapConfig:
    """Knobs of :func:`undo_limb_swaps` (seconds, metres)."""

    min_offset_m: float = 0.08
    ratio: float = 0.5
    max_swap_s: float = 0.7


def _runs(active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.concatenate([[False], active, [False]]).astype(np.int8)
    d = np.diff(a)
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


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
    T = x.shape[0]
    if T < 4 or not pairs:
        return out, mask
    longest = max(1, int(round(cfg.max_swap_s * rate_hz)))
    for a, b in pairs:
        both = np.concatenate([a, b])
        mirrored = np.concatenate([b, a])
        # predicts frames 1..T-1: frame 1 from frame 0 alone (no velocity yet), so a swap that
        # begins on a take's second frame is seen beginning
        pred = np.concatenate([x[:1, both], 2.0 * x[1:-1, both] - x[:-2, both]])
        keep = point_norms(x[1:, both] - pred)
        cross = point_norms(x[1:, mirrored] - pred)
        # joints seen in all three frames, both labellings; a frame is judged on at least half
        # of them (one joint the engine left out of a window's clean history must not hide
        # the toggle where a swap that began before the window ends)
        seen = np.isfinite(keep) & np.isfinite(cross)
        n_seen = seen.sum(axis=1)
        ok = n_seen >= max(1, (len(both) + 1) // 2)
        k = np.where(ok, np.where(seen, keep, 0.0).sum(axis=1) / np.maximum(n_seen, 1), 0.0)
        c = np.where(ok, np.where(seen, cross, 0.0).sum(axis=1) / np.maximum(n_seen, 1), np.inf)
        toggle = np.zeros(T, dtype=bool)
        toggle[1:] = ok & (k > cfg.min_offset_m) & (c < cfg.ratio * k)
        if not toggle.any():
            continue
        swapped = (np.cumsum(toggle) % 2).astype(bool)
        starts, ends = _runs(swapped)
        for s0, e0 in zip(starts, ends):  # a few runs per window
            if e0 - s0 > longest or e0 == T and s0 == 0:
                swapped[s0:e0] = False
        if swapped.any():
            rows = np.flatnonzero(swapped)
            out[rows[:, None], both[None, :]] = x[rows[:, None], mirrored[None, :]]
            mask[rows[:, None], both[None, :]] = True
    return out, mask
