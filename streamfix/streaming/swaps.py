"""Left/right swaps in one engine window: :func:`streamfix.core.swaps.undo_limb_swaps` seen
with the body's clean history.

A swap shows as a toggle between consecutive frames, so the frames just before the window
matter: the window is extended by the body's clean history (already unswapped, and kept
there because relabelled joints are not flagged recovered) and only the window's rows are
returned.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..core.swaps import SwapConfig, undo_limb_swaps
from ..limbs import limb_groups
from ..skeletons import Skeleton

__all__ = ["unswap_window"]


@lru_cache(maxsize=64)
def _groups(skeleton: Skeleton) -> tuple:
    return tuple(limb_groups(skeleton))


def unswap_window(
    positions: np.ndarray,
    observed: np.ndarray,
    skeleton: Skeleton,
    rate_hz: float,
    history: np.ndarray | None = None,
    cfg: SwapConfig = SwapConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """Window ``(T, J, 3)`` m with swapped limbs exchanged back, and the ``(T, J)`` mask of
    the joint-frames exchanged."""
    x = np.asarray(positions, dtype=np.float64)
    groups = list(_groups(skeleton))
    if not groups:
        return x, np.zeros(x.shape[:2], dtype=bool)
    T = len(x)
    keep = int(round(cfg.max_swap_s * rate_hz))  # a swap that began before the window is in here
    h = np.zeros((0,) + x.shape[1:]) if history is None or len(history) == 0 else np.asarray(history, dtype=np.float64)[-keep:]
    ext = np.concatenate([h, np.where(observed[..., None], x, np.nan)])
    fixed, mask = undo_limb_swaps(ext, groups, rate_hz, cfg)
    mine = mask[len(h):]
    if not mine.any():
        return x, mine
    return np.where(mine[..., None], fixed[len(h):], x), mine
