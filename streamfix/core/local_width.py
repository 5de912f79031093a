"""Per-frame choice of the robust fit's half-width: the candidate whose bones stay rigid here.

Why: stage 1 of :func:`streamfix.core.pipeline.clean_window` fits every coordinate with
several candidate half-widths and scores each by how little the bone lengths of its
estimate vary. One score per window is a compromise when the motion's speed changes
inside the window (an arm at rest, then raised in a quarter second): the wide fit that
suits the still part lags the fast onset, its samples there are flagged and replaced by
the lagging fit, and the limb's bones stretch exactly where the fast part is. Scored frame
by frame over a short neighbourhood, each part of the window takes the half-width its
own bones prefer. The choice is a fractional candidate index, smoothed over a few frames
and interpolated between neighbouring candidates' fits, so switching widths adds no kink.
Pure arrays in, arrays out.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from .isometry import bone_lengths_per_frame
from .robust_stats import nanmedian

__all__ = ["frame_bone_deviation", "frame_bone_deviations", "frame_sums", "local_width_index", "take_fractional"]


def frame_bone_deviations(
    positions: np.ndarray, observed: np.ndarray, bones: np.ndarray, min_bone_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(deviations (T, B), counted (B,))``: each bone's ``|l_t - median_t l|`` (m; NaN where
    an end is not ``observed``) and whether the bone counts (typical length above
    ``min_bone_m``: the bones :func:`streamfix.core.isometry.bone_length_deviations` counts).
    The numpy reference of :func:`streamfix.core.kernels.bone_spread_deviations` with ``frames=True``."""
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    seen = observed[:, b[:, 0]] & observed[:, b[:, 1]]
    lengths = np.where(seen, bone_lengths_per_frame(positions, b), np.nan)
    typical = nanmedian(lengths, axis=0)
    with np.errstate(invalid="ignore"):
        return np.abs(lengths - typical), typical > min_bone_m


def frame_bone_deviation(
    positions: np.ndarray, observed: np.ndarray, bones: np.ndarray, min_bone_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame ``(T,)``: the sum over the counted bones of ``|l_t - median_t l|`` (m) and how
    many bones it sums (:func:`frame_bone_deviations`)."""
    return frame_sums(*frame_bone_deviations(positions, observed, bones, min_bone_m))


def frame_sums(deviations: np.ndarray, counted_bones: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`frame_bone_deviation`'s ``(sums, counts)`` from per-frame bone deviations
    ``(T, B)`` (m, NaN where not seen) and the bones that count ``(B,)`` bool: what a caller
    that already has the deviations (:func:`streamfix.core.kernels.bone_spread_deviations`)
    needs, summed exactly as the reference sums them."""
    dev = deviations[:, np.asarray(counted_bones, dtype=bool)]
    counted = np.isfinite(dev)
    return np.where(counted, dev, 0.0).sum(axis=1), counted.sum(axis=1).astype(np.float64)


def local_width_index(
    deviation_sums: np.ndarray, counts: np.ndarray, score_frames: int, smooth_frames: int
) -> np.ndarray:
    """``(T,)`` fractional index into the candidates: per frame, the candidate whose mean bone
    deviation over the ``2 score_frames + 1`` frames around it is least (the first of equal
    scores, i.e. the shortest half-width), averaged over ``2 smooth_frames + 1`` frames
    (edges repeated) so the choice changes gradually.

    ``deviation_sums`` / ``counts`` ``(K, T)``: :func:`frame_bone_deviation` per candidate,
    candidates in ascending half-width. A frame with no bone near it takes candidate 0.
    """
    sums = np.asarray(deviation_sums, dtype=np.float64)
    n = np.asarray(counts, dtype=np.float64)
    box = np.ones(2 * int(score_frames) + 1)
    num = correlate1d(sums, box, axis=1, mode="constant")
    den = correlate1d(n, box, axis=1, mode="constant")
    score = np.where(den > 0, num / np.maximum(den, 1e-12), np.inf)
    index = np.argmin(score, axis=0).astype(np.float64)  # all inf: 0
    s = int(smooth_frames)
    if s > 0 and index.size:
        index = correlate1d(index, np.full(2 * s + 1, 1.0 / (2 * s + 1)), mode="nearest")
    return index


def take_fractional(stack: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``stack`` ``(K, T, ...)`` read at a fractional candidate ``index`` ``(T,)`` per frame:
    linear between the two neighbouring candidates. Returns ``(T, ...)``."""
    k = stack.shape[0]
    lo = np.clip(np.floor(index).astype(np.intp), 0, k - 1)
    hi = np.minimum(lo + 1, k - 1)
    a = (index - lo).reshape((-1,) + (1,) * (stack.ndim - 2))
    frames = np.arange(stack.shape[1])
    return (1.0 - a) * stack[lo, frames] + a * stack[hi, frames]
