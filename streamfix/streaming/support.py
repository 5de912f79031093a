"""Foot support for one engine window: :func:`streamfix.core.support.plant_supporting_feet`
seen with the body's clean history.

A window is 2 s; a squat or a sit lasts longer, and the floor and where each foot last
stood are facts about the past. So the window is extended by the body's clean history
(the engine's ``history=``, recovered samples NaN) before the floor, the up direction and
the anchors are found, and only the window's rows are returned. Frames where a leg joint
is missing or not trusted are left alone (their weight is 0) but keep their place in time.
"""
from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..core.support import SupportConfig, plant_supporting_feet, up_direction
from ..limbs import LimbLayout, limb_layout
from ..skeletons import Skeleton

__all__ = ["plant_window", "layout_of"]


@lru_cache(maxsize=64)
def layout_of(skeleton: Skeleton) -> LimbLayout:
    """:func:`streamfix.limbs.limb_layout`, cached per skeleton (called every window)."""
    return limb_layout(skeleton)


class _LegJoints(NamedTuple):
    """The joints foot support reads (legs, shoulders) and their indices renumbered into that subset."""
    used: np.ndarray  # (U,) layout joints read, ascending
    legs: np.ndarray  # (2, 4) hip, knee, ankle, foot per side, indices into ``used``
    shoulders: np.ndarray | None  # (2,) into ``used``, or None
    need: np.ndarray  # every leg and shoulder joint, into ``used``


@lru_cache(maxsize=64)
def _leg_joints(skeleton: Skeleton) -> _LegJoints:
    """:class:`_LegJoints` of a skeleton whose layout has legs, cached (called every window)."""
    layout = layout_of(skeleton)
    need = layout.legs.ravel() if layout.shoulders is None else np.concatenate([layout.legs.ravel(), layout.shoulders])
    used = np.unique(need)
    shoulders = None if layout.shoulders is None else np.searchsorted(used, layout.shoulders)
    return _LegJoints(used, np.searchsorted(used, layout.legs), shoulders, np.searchsorted(used, need))


def _leg_lengths(legs: np.ndarray, bones: np.ndarray, bone_lengths: np.ndarray | None) -> np.ndarray | None:
    """``(2, 2)`` thigh and shin lengths from the engine's bone-length estimate, if it has them."""
    if bone_lengths is None or len(bones) == 0:
        return None
    index = {(int(a), int(b)): k for k, (a, b) in enumerate(np.asarray(bones).reshape(-1, 2))}
    out = np.full((2, 2), np.nan)
    for s in range(2):
        for c, (p, q) in enumerate(((legs[s, 0], legs[s, 1]), (legs[s, 1], legs[s, 2]))):
            k = index.get((int(p), int(q)), index.get((int(q), int(p))))
            if k is not None:
                out[s, c] = float(bone_lengths[k])
    return out if np.isfinite(out).all() else None


def plant_window(
    positions: np.ndarray,
    observed: np.ndarray,
    skeleton: Skeleton,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None,
    rate_hz: float,
    history: np.ndarray | None = None,
    cfg: SupportConfig = SupportConfig(),
    trusted: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Window ``(T, J, 3)`` m with wrongly lifted feet planted, and the ``(T, J)`` weight of
    the correction on each joint (0 = untouched; knees, ankles and feet only).

    ``trusted`` ``(T, J)``: where the sensor vouches for a joint (tracked, not inferred).
    A frame whose leg joints are not all trusted is left out: there the sensor already says
    a leg is a guess (a frozen or drifting inferred leg), which is not the both-feet-lifted
    failure, and planting the other, tracked leg would only damage it.
    """
    x = np.asarray(positions, dtype=np.float64)
    T, J = x.shape[:2]
    weight = np.zeros((T, J))
    layout = layout_of(skeleton)
    if layout.legs is None or T < 2:
        return x, weight
    legs = layout.legs
    # only the legs and shoulders are read: the window and its history (seconds of frames)
    # cut down to them, with the leg and shoulder indices renumbered into the cut
    used, sub_legs, sub_shoulders, sub_need = _leg_joints(skeleton)
    n_hist = 0 if history is None else len(history)
    ok = observed if trusted is None else observed & trusted
    ext = np.empty((n_hist + T, len(used), 3))
    if n_hist:
        ext[:n_hist] = np.asarray(history, dtype=np.float64)[:, used]
    ext[n_hist:] = np.where(ok[:, used, None], x[:, used], np.nan)
    # a frame without every leg joint trusted makes no decision (NaN heights), but keeps its
    # place on the timeline: the minimum run length and the anchors are about time
    unusable = ~np.isfinite(ext[:, sub_need]).all(axis=(1, 2))
    ext[np.ix_(unusable, sub_legs.ravel())] = np.nan
    if (~unusable[n_hist:]).sum() < 2:
        return x, weight
    up = up_direction(ext[~unusable], sub_legs, sub_shoulders, cfg.axis_snap_cos, cfg.upright_cos,
                      int(round(cfg.upright_min_s * rate_hz)))
    fixed, w, _ = plant_supporting_feet(ext, sub_legs, up, rate_hz, _leg_lengths(legs, bones, bone_lengths), cfg)
    w = w[n_hist:]
    if not w.any():
        return x, weight
    cols = legs[:, 1:].ravel()
    rows = np.flatnonzero(w > 0)
    out = x.copy()
    out[np.ix_(rows, cols)] = fixed[n_hist:][np.ix_(rows, sub_legs[:, 1:].ravel())]
    weight[np.ix_(rows, cols)] = w[rows, None]
    return out, weight
