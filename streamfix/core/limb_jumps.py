"""A limb that jumps as one piece for a few frames: a depth sensor's gross failure.

Why: a Kinect that misreads a forearm or a shin for a few frames moves the whole limb below
the elbow or knee by 15 cm or more and puts it back (the sensor protocol's ``jump``, measured
on UI-PRMD's Kinect v1 against Vicon: ``docs/SENSOR_ERRORS.md``). The limb keeps its own
bones, so only the bone joining it to the body (the upper arm, the thigh) changes length,
and the window cleaner's per-frame rigidity score, a mean over every bone, dilutes that one
bone: its robust fit followed such a group in most windows (``tests/test_core_pipeline.py``).

The signature is specific, and this module looks for nothing else: one bone off its length
by more than its own noise allows, abruptly, for a short run with good frames on both
sides, while the bones below its distal joint and the other bones at its proximal joint keep
their lengths. Then the distal side moved as one piece: its samples in the run are released
(made missing) and the window's gap fill replaces them from the frames around and the other
joints. A joint thrown alone stretches the bones on both of its sides and is the robust
fit's outlier; a body part whose bones all wander (a window under heavy corruption) shows
no such isolated run and is left to the robust fit too.

Arrays: positions ``(T, J, 3)`` metres, observed ``(T, J)`` bool, bones ``(B, 2)`` (parent, child).
"""
from __future__ import annotations

import numpy as np

from .bone_rotations import subtree_mask
from .excursion import parents_from_bones
from .interpolate import missing_run_lengths
from .isometry import bone_lengths_per_frame
from .points import finite_points
from .robust_stats import nanmedian

__all__ = ["jumped_limbs", "MIN_BONE_M", "FLOOR_M", "NOISE_MULTIPLE", "MIN_RUN_S", "MAX_RUN_S", "ABRUPT_FRACTION",
           "NEIGHBOUR_SHARE", "MAX_DEVIANT_SHARE"]

MIN_BONE_M = 0.15
"""Only bones at least this long (m) decide: an upper arm, forearm, thigh or shin, a spine
segment. A hand, foot, thumb or collar bone is too short to tell a jump from its noise."""

FLOOR_M = 0.04
"""A bone's length must be off by more than this (m)... (a 15 cm jump changes a 28 cm upper
arm's length by 4.8 cm or more in most directions)."""

NOISE_MULTIPLE = 5.0
"""...and by more than this many times the bone's own length noise over the window (1.4826 x
the median absolute deviation from its length): Kinect v1 collar and hip bones, and a v2
shoulder, stretch by centimetres with the pose."""

MIN_RUN_S = 0.1
"""Shortest run (s) released: a bone off for a frame or two is the robust temporal fit's
outlier (its half-widths reach 2 frames and more), and a one-frame misreading of a Kinect
forearm's length is common where the arm moves fast (KERAAL)."""

MAX_RUN_S = 0.4
"""Longest run (s) released: the sensor protocol's jumps last 3-9 frames at 30 Hz. A longer
stretch is a slow change of the sensor's joint centres or a lost limb (core/frozen.py,
core/dislocated.py), not a jump."""

ABRUPT_FRACTION = 0.5
"""The length must change by at least this fraction of the threshold from the frame before
the run to its first frame, and from its last frame to the frame after: a jump starts and
ends within a frame; a pose-driven stretch builds up."""

NEIGHBOUR_SHARE = 2.0 / 3.0
"""Share of the run's frames in which each bone below the distal joint and each other bone at
the proximal joint must keep its length (within its own threshold): where they do not, a
joint moved alone or the whole region is off, and the robust fit is the better judge."""

MAX_DEVIANT_SHARE = 0.1
"""When more than this share of the deciding bones' frames are off their lengths, the window
is corrupted throughout (the paper's protocol: most entries noisy) and no run is an event."""


def jumped_limbs(
    positions: np.ndarray,
    observed: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None,
    rate_hz: float,
) -> np.ndarray:
    """``(T, J)`` bool: the observed samples of a limb that jumped as one piece (module doc).

    ``bone_lengths`` ``(B,)`` m: the body's lengths (NaN or None: the bone's median over the
    window's observed frames); ``rate_hz`` turns ``MIN_RUN_S`` and ``MAX_RUN_S`` into frames.
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool) & finite_points(x)
    T, J = obs.shape
    out = np.zeros((T, J), dtype=bool)
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if T < 3 or not len(b):
        return out
    seen = obs[:, b[:, 0]] & obs[:, b[:, 1]]
    length = np.where(seen, bone_lengths_per_frame(x, b), np.nan)  # (T, B)
    given = None if bone_lengths is None else np.asarray(bone_lengths, dtype=np.float64)
    if given is not None and np.isfinite(given).all():
        target = given  # the body's lengths (the streaming engine's): no median needed
    else:
        target = nanmedian(length, axis=0)
        if given is not None:
            target = np.where(np.isfinite(given), given, target)
    deciding = np.isfinite(target) & (target >= MIN_BONE_M)
    with np.errstate(invalid="ignore"):
        dev = length - target
        if not (np.abs(dev[:, deciding]) > FLOOR_M).any():
            return out  # no deciding bone past the floor anywhere: the common window, decided cheaply
        noise = 1.4826 * nanmedian(np.abs(dev - nanmedian(dev, axis=0)), axis=0)
        threshold = np.maximum(FLOOR_M, NOISE_MULTIPLE * np.nan_to_num(noise))  # (B,)
        off = np.abs(dev) > threshold  # NaN (unseen): not off
    if not (off[:, deciding]).any() or off[:, deciding].mean() > MAX_DEVIANT_SHARE:
        return out
    min_run = max(1, int(round(MIN_RUN_S * rate_hz)))
    max_run = max(min_run, int(round(MAX_RUN_S * rate_hz)))
    run = missing_run_lengths(~off)  # (T, B): each off sample's run length
    candidate = off & (run >= min_run) & (run <= max_run) & deciding[None, :]
    if not candidate.any():
        return out
    parents = parents_from_bones(b, J)
    for k in np.flatnonzero(candidate.any(axis=0)):
        p, c = b[k]
        # the other bones at the proximal joint and the bones below the distal one
        neighbours = np.flatnonzero(((b[:, 0] == p) | (b[:, 1] == p) | (b[:, 0] == c)) & (np.arange(len(b)) != k))
        edges = np.flatnonzero(np.diff(np.concatenate([[0], candidate[:, k].astype(np.int8), [0]])))
        for s, e in zip(edges[::2], edges[1::2]):  # each run [s, e): a few events per window at most
            if s == 0 or e == T or not (seen[s - 1, k] and seen[e, k]):
                continue  # open at the window's edge, or no good frame beside it: not judged here
            step = ABRUPT_FRACTION * threshold[k]
            if abs(length[s, k] - length[s - 1, k]) < step or abs(length[e - 1, k] - length[e, k]) < step:
                continue
            kept = True
            for n in neighbours:
                judged = seen[s:e, n]
                if judged.any() and (~off[s:e, n][judged]).mean() < NEIGHBOUR_SHARE:
                    kept = False
                    break
            if kept:
                out[s:e] |= subtree_mask(parents, c)[None, :]
    return out & obs
