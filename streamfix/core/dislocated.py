"""Hands and feet a sensor holds at an impossible distance from the joint they hang on.

Why: a depth sensor that loses a hand or a foot often keeps reporting it, *tracked*, at
the wrong place: the hand collapses onto the wrist (KERAAL's Kinect v2 with the arms
overhead: the wrist-hand bone at 2.2 cm of its 5.9 for the last 0.8 s of the take, the
hand 14 cm from the Vicon) or a foot folds onto the ankle. Such a plateau lasts longer
than the robust temporal fit's half-width, so the fit follows it and the samples are not
outliers; the bone projection then restores the length but splits the error between the
two ends, leaving the hand where the sensor put it. A bone far off its length for a run of
frames says the sample is not a measurement, so it is released and put back on its parent
(:func:`parent_relative_fill`): the joint's offset to its parent in the good samples around
the run, interpolated in time, at the body's bone length.

Only the *end* segments are judged: a bone whose distal joint carries at most
``MAX_SUBTREE`` joints (a hand with its tip, a foot, a thumb, a head). A longer chain (a hip
or collar bone, whose distal joint carries a whole limb) is not released for one bone's
length: on UI-PRMD's Kinect v1 the short hip and collar bones leave half their length
for a second at a time while the limb below is tracked well, and releasing a limb for it
would replace good samples. The end segments' lengths are noisy (a Kinect thumb or hand
tip jitters by a third of its length), so a sample counts only when the error exceeds
``FRACTION`` of the length *and* ``FLOOR_M``, for ``MIN_RUN_S`` or longer (shorter
failures are the temporal fit's outliers).

Arrays: positions ``(T, J, 3)`` metres, confidence ``(T, J)``, bones ``(B, 2)`` (parent, child).
"""
from __future__ import annotations

import functools

import numpy as np

from .bone_rotations import subtree_mask, topological_order
from .excursion import bone_into, parents_from_bones
from .interpolate import interpolate_linear, missing_run_lengths
from .points import finite_points, point_norms

__all__ = ["dislocated_ends", "end_segments", "parent_relative_fill", "FRACTION", "FLOOR_M", "MIN_RUN_S", "PROXIMAL_FRACTION", "MAX_SUBTREE"]

FRACTION = 0.5
"""A bone's length error, as a fraction of its length, beyond which a sample is impossible."""

FLOOR_M = 0.03
"""...and beyond this (m): a Kinect hand tip or thumb, 3-7 cm long, jitters by a centimetre
or more at each end, and the sensor protocol's correlated noise alone often put such bones
past 2.5 cm for a sixth of a second in its takes (less often past 3 cm)."""

MIN_RUN_S = 1.0 / 3.0
"""Shortest run (s) of such samples released. Shorter failures are the temporal fit's
outliers; and a bone does not say which of its ends is wrong, so a wrist thrown off for a
few frames (the sensor protocol's jumps last 3-9 frames) would release the hand below it."""

PROXIMAL_FRACTION = 0.2
"""The bone into the proximal joint must be within this fraction of its length: KERAAL's
forearm was 9 % short while the hand lay on the wrist; a wrist thrown 15 cm or more (the
sensor protocol's jumps) leaves a 25 cm forearm outside it in most directions."""

MAX_SUBTREE = 2
"""Most joints an end segment's distal joint may carry, itself included (a hand and its tip)."""


def end_segments(bones: np.ndarray, n_joints: int, max_subtree: int = MAX_SUBTREE) -> np.ndarray:
    """``(B, J)`` bool: for each bone whose distal joint carries at most ``max_subtree``
    joints (itself included), those joints; all False for the other bones."""
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    parents = parents_from_bones(b, n_joints)
    subtree = np.array([subtree_mask(parents, c) for c in b[:, 1]], dtype=bool).reshape(len(b), n_joints)
    return subtree & (subtree.sum(axis=1) <= max_subtree)[:, None]


@functools.lru_cache(maxsize=32)
def _end_segments_cached(bones_bytes: bytes, n_joints: int, max_subtree: int) -> np.ndarray:
    """:func:`end_segments` of one skeleton, computed once (read-only)."""
    seg = end_segments(np.frombuffer(bones_bytes, dtype=np.intp).reshape(-1, 2), n_joints, max_subtree)
    seg.setflags(write=False)
    return seg


def dislocated_ends(
    positions: np.ndarray,
    confidence: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None,
    rate_hz: float,
    *,
    fraction: float = FRACTION,
    floor_m: float = FLOOR_M,
    min_run_s: float = MIN_RUN_S,
    max_subtree: int = MAX_SUBTREE,
    joints: np.ndarray | None = None,
    proximal_fraction: float = PROXIMAL_FRACTION,
) -> np.ndarray:
    """``(T, J)`` bool: the samples of an end segment (:func:`end_segments`) whose *tracked*
    distal joint's bone to its parent is off its length by more than ``fraction`` of it and
    ``floor_m`` for at least ``min_run_s`` seconds in a row. ``bone_lengths`` ``(B,)`` m: the body's lengths
    (NaN: that bone is not judged); None: nothing is judged. Never the window's own: at a
    stream's start a 16-frame window whose wrist the sensor threw off for half of it has a
    median hand bone between the two, and every one of its frames looked off.
    A sample counts only where the bone into the proximal joint is within
    ``proximal_fraction`` of its length (that joint is where its bone allows).
    ``joints`` ``(J,)`` bool: only end segments whose distal joint is one of these (None = any;
    the bridge passes the limbs', so a neck and head are not judged by one short bone)."""
    conf = np.asarray(confidence, dtype=np.float64)
    T, J = conf.shape
    out = np.zeros((T, J), dtype=bool)
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if T == 0 or not len(b) or bone_lengths is None:
        return out
    ends = _end_segments_cached(b.tobytes(), J, max_subtree)
    judged = ends.any(axis=1)
    if joints is not None:
        judged &= np.asarray(joints, dtype=bool)[b[:, 1]]
    if not judged.any():
        return out
    target = np.asarray(bone_lengths, dtype=np.float64)
    x = np.asarray(positions, dtype=np.float64)
    k = np.flatnonzero(judged)
    # tracked distal ends only: an inferred hand or foot is the sensor's guess, judged by the
    # frozen-limb stage; released here for its length, a seated user's inferred feet under a
    # desk (seated_joints.csv) were filled further off their mirrors' lengths
    seen = (conf[:, b[k, 0]] > 0) & (conf[:, b[k, 1]] >= 1.0)
    error = np.abs(point_norms(x[:, b[k, 1]] - x[:, b[k, 0]]) - target[k])  # NaN: an end or the length unknown
    bad = seen & (error > np.maximum(fraction * target[k], floor_m))
    if not bad.any():
        return out
    # a bone does not say which of its ends is wrong: the distal one is released only where
    # the proximal one sits where its own bone allows (a wrist thrown off stretches the hand's
    # bone too, and it is the wrist that is wrong)
    up = bone_into(b, J)[b[k, 0]]  # the bone into each judged bone's proximal joint, -1 at a root
    has_up = up >= 0
    if has_up.any():
        u = up[has_up]
        up_seen = (conf[:, b[u, 0]] > 0) & (conf[:, b[u, 1]] > 0)
        up_error = np.abs(point_norms(x[:, b[u, 1]] - x[:, b[u, 0]]) - target[u])
        bad[:, has_up] &= up_seen & (up_error <= proximal_fraction * target[u])
    run = missing_run_lengths(~bad)  # the length of each run of bad samples
    bad &= run >= max(1, int(round(min_run_s * rate_hz)))
    if bad.any():
        out = (bad.astype(np.float64) @ ends[k].astype(np.float64)) > 0
        out &= conf > 0
    return out


def parent_relative_fill(positions: np.ndarray, released: np.ndarray, observed: np.ndarray, bones: np.ndarray,
                         bone_lengths: np.ndarray) -> np.ndarray:
    """``(T, J, 3)`` m: each released sample of ``positions`` put back on its parent from
    the joint's offset to the parent in the good samples around the run, interpolated
    linearly in time (held where the run has one end) and scaled to the bone's length in
    ``bone_lengths`` ``(B,)`` m (NaN: the interpolated offset as it is); NaN where the joint
    has no good sample. A hand tip below a released hand follows the hand's fill (parents first).

    Why not the window solver: a released hand or foot hangs from a parent the sensor has
    right (its bone into the parent is checked), and its own motion over a third of a second
    is its parent's plus a turn; the low-rank solve and the PCA bridge it would trigger cost
    much of the engine's time on Kinect v2 recordings whose hands fail every few seconds,
    to place 2-3 joints. ``observed`` ``(T, J)``: the good samples."""
    x = np.array(positions, dtype=np.float64)
    rel = np.asarray(released, dtype=bool)
    if not rel.any():
        return x
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    J = x.shape[1]
    parents = parents_from_bones(b, J)
    length = np.asarray(bone_lengths, dtype=np.float64)[bone_into(b, J)]
    good = np.asarray(observed, dtype=bool) & ~rel
    order = topological_order(parents)
    todo = rel.any(axis=0) & (parents >= 0)
    for j in order[todo[order]]:  # parents first: a released hand tip after its hand
        p = parents[j]
        offset = np.where((good[:, j] & good[:, p])[:, None], x[:, j] - x[:, p], np.nan)[:, None]
        est = interpolate_linear(offset, finite_points(offset))[0][:, 0]
        if np.isfinite(length[j]):
            norm = np.linalg.norm(est, axis=1, keepdims=True)
            est = est * (length[j] / np.where(norm > 0, norm, 1.0))  # the bone's length, not the chord's
        x[rel[:, j], j] = x[rel[:, j], p] + est[rel[:, j]]
    x[rel & ~finite_points(x)] = np.nan
    return x
