"""Tell fast real motion from outliers by the skeleton's rigidity (pure math, arrays in and out).

Why: the robust temporal fit (:mod:`streamfix.core.pipeline`, stage 1) flags every
sample it cannot follow, and a local quadratic over a few frames cannot follow a kick,
a punch or a fast wave: on exact mocap the outlier stage replaced such samples by the
fit, centimetres to decimetres off the truth (``benchmarks/bench_sensor.py`` scores the
damage on uncorrupted joints as collateral). Time alone cannot tell such motion from a
spike; the skeleton can. An outlier (a spike, a joint or a limb's distal part thrown
off) breaks the lengths of the bones it shares with the rest of the body, and replacing
it by the fit restores them; a real fast movement keeps every bone's length, and
replacing it by the smooth fit is what breaks them.

:func:`rigid_motion` compares, for each connected group of flagged joints at a frame
(joints linked by bones or rigid marker pairs), the bone-length error of the raw samples
with that of the replacement, over every bone touching the group. The group is motion
when the raw samples are rigid (within ``RIGID_TOLERANCE_M`` per bone) and clearly more
rigid than the replacement (``RIGID_MOTION_RATIO``), and the group hangs on the rest of
the body by a bone. A flagged joint all of whose judged bones are broken is the outlier
itself (a spike on the thumb of a fast hand): it stays flagged, and the rest of its group is
judged without it. The test only speaks where the skeleton is rigid in the first place
(animation, solved optical mocap): a depth sensor's bones vary by millimetres to
centimetres, rigidity at a 2 mm tolerance shows nothing there, and such windows (and
marker sets whose most rigid pairs still vary by a few millimetres) keep the fit's verdict.
"""
from __future__ import annotations

import numpy as np

from .isometry import bone_length_deviations, bone_lengths_per_frame, incidence_matrix
from .robust_stats import nanmedian

__all__ = ["rigid_motion", "RIGID_MOTION_RATIO", "RIGID_MOTION_FLOOR_M", "RIGID_TOLERANCE_M", "RIGID_SKELETON_QUANTILE"]

RIGID_MOTION_RATIO = 0.5
"""A flagged group is kept raw when its raw bone-length error is at most this share of the replacement's."""
RIGID_MOTION_FLOOR_M = 0.002
"""... and the replacement's error exceeds this (m): where both are near rigid, the fit's
verdict stands (a whole group displaced together keeps its own bones either way)."""
RIGID_TOLERANCE_M = 0.002
"""... and the raw group's bones are within this of their reference lengths on average (m):
rigid in fact (optical mocap, animation), not only more rigid than the fit (a depth
sensor's bones vary by centimetres, and its samples keep the fit's verdict)."""
RIGID_SKELETON_QUANTILE = 75.0
"""The skeleton is rigid when this percentile over bones of each bone's median deviation from
its typical length (unflagged frames) is at most half of ``RIGID_TOLERANCE_M``. A quarter of
the bones may vary (a limb's worth: a frozen or drifting leg, retargeted hand tips): at the
90th percentile three such bones of 24 made an exact skeleton look like a depth sensor's, and
a fast exact arm next to a frozen leg was replaced by the fit (far off for a frame on a
sensor-protocol freeze take); a depth sensor's bones nearly all vary."""
MIN_REFERENCE_FRAMES = 5
MIN_REFERENCE_SHARE = 0.25
"""A bone's reference length needs this many (and this share of the window's) frames with
both ends observed and unflagged; a bone without one gives no evidence."""


def _closure(adjacency: np.ndarray) -> np.ndarray:
    """Reachability ``(T, J, J)`` (0/1 floats) of per-frame undirected graphs given with self
    loops, by repeated squaring (at most ceil(log2 J) products)."""
    reach = adjacency
    for _ in range(max(1, int(np.ceil(np.log2(max(adjacency.shape[1], 2)))))):
        nxt = ((reach @ reach) > 0).astype(np.float64)
        if np.array_equal(nxt, reach):
            break
        reach = nxt
    return reach


def rigid_motion(
    raw: np.ndarray,
    replaced: np.ndarray,
    flagged: np.ndarray,
    observed: np.ndarray,
    pairs: np.ndarray,
    min_length_m: float,
    ratio: float = RIGID_MOTION_RATIO,
    floor_m: float = RIGID_MOTION_FLOOR_M,
    tolerance_m: float = RIGID_TOLERANCE_M,
) -> np.ndarray:
    """Flagged joint-frames ``(T, J)`` whose raw samples are rigid motion, not outliers.

    raw, replaced: ``(T, J, 3)`` m, the samples and the same with the flagged ones replaced
    by the temporal fit. flagged, observed: ``(T, J)`` bool. pairs: ``(B, 2)`` joint
    indices of bones (or rigid marker pairs); pairs shorter than ``min_length_m`` are
    ignored. A bone's reference length is its median over the frames where both ends are
    observed and unflagged, on at least ``MIN_REFERENCE_FRAMES`` and ``MIN_REFERENCE_SHARE``
    of the frames (other bones give no evidence). Only a rigid skeleton is judged: where the
    ``RIGID_SKELETON_QUANTILE`` % quantile over bones of their median deviation on those
    frames exceeds half of ``tolerance_m`` (a depth sensor's skeleton), nothing is kept.
    """
    flagged = np.asarray(flagged, dtype=bool)
    out = np.zeros_like(flagged)
    p = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    if not flagged.any() or len(p) == 0:
        return out
    # rigidity is evidence only where the skeleton is rigid: a solved mocap or animated
    # skeleton, not a depth sensor's, whose bones vary by millimetres to centimetres even
    # on unflagged frames (then nothing is kept, and the fit's verdict stands)
    spread = bone_length_deviations(raw, observed & ~flagged, p, min_length_m)
    spread = spread[np.isfinite(spread)]
    if not spread.size or not np.percentile(spread, RIGID_SKELETON_QUANTILE) <= 0.5 * tolerance_m:
        return out
    a, b = p[:, 0], p[:, 1]
    both = observed[:, a] & observed[:, b]
    raw_len = bone_lengths_per_frame(raw, p)
    clean = both & ~flagged[:, a] & ~flagged[:, b]
    ref = nanmedian(np.where(clean, raw_len, np.nan), axis=0)
    # a reference needs enough unflagged frames (heavily corrupted windows have none to trust)
    known = clean.sum(axis=0) >= max(MIN_REFERENCE_FRAMES, MIN_REFERENCE_SHARE * len(raw))
    usable = known & np.isfinite(ref) & (ref > min_length_m)
    if not usable.any():
        return out
    deviation = np.abs(raw_len - ref)
    rows = np.flatnonzero(flagged.any(axis=1))  # only frames with a flagged joint are judged
    f, use = flagged[rows], both[rows] & usable[None, :]
    n_joints = flagged.shape[1]
    incidence = np.abs(incidence_matrix(p, n_joints))  # (B, J): 1 at both ends of each bone
    # a flagged joint every judged bone of which is broken is the outlier itself (a spike on a
    # thumb of a fast hand): it stays flagged, and its bones neither judge nor anchor the rest
    # of its group, which is judged without it
    judged = (use & (f[:, a] | f[:, b])).astype(np.float64) @ incidence
    broken = (use & (deviation[rows] > tolerance_m)).astype(np.float64) @ incidence
    culprit = f & (judged > 0) & (broken >= judged)
    if culprit.any():
        f = f & ~culprit
        use = use & ~culprit[:, a] & ~culprit[:, b]
    fa, fb = f[:, a], f[:, b]
    touch = use & (fa | fb)
    rep_len = bone_lengths_per_frame(replaced[rows], p)
    # per flagged joint: bone-length error (raw, replaced), bones judged, bones to unflagged joints
    per_joint = np.stack([
        np.where(touch, deviation[rows], 0.0) @ incidence,
        np.where(touch, np.abs(rep_len - ref), 0.0) @ incidence,
        touch.astype(np.float64) @ incidence,
        (use & (fa ^ fb)).astype(np.float64) @ incidence,
    ], axis=2) * f[..., None]
    # groups: flagged joints joined by bones whose two ends are both flagged
    adjacency = np.zeros((len(rows), n_joints, n_joints))
    linked = (fa & fb & both[rows]).astype(np.float64)
    adjacency[:, a, b] = linked
    adjacency[:, b, a] = linked
    adjacency[:, np.arange(n_joints), np.arange(n_joints)] = 1.0
    group_raw, group_rep, group_bones, group_boundary = np.moveaxis(_closure(adjacency) @ per_joint, 2, 0)
    rigid_raw = group_raw <= tolerance_m * np.maximum(group_bones, 1.0)
    # attached to the rest of the body by a bone to an unflagged joint: a group with no such
    # bone (the whole body flagged at once) keeps its bones whether it moved or the sensor shook
    anchored = group_boundary > 0
    out[rows] = f & anchored & rigid_raw & (group_rep > floor_m) & (group_raw <= ratio * group_rep)
    return out
