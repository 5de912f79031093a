"""Accuracy and smoothness metrics (Yang et al. 2019, Section IV, plus jitter and bone CV).

With ground truth ``n~`` and reconstruction ``n``, both ``(T, J, 3)`` metres:

* AJE  omega = 1/(S T) sum_t sum_p d(n~_p^t, n_p^t)           (Section IV, d = Euclidean)
* ABE  xi    = 1/(T (S-1)) sum_t sum_{e_ij in E} |l~_ij^t - l_ij^t|   (Section IV; S-1 = number
  of bones for a tree skeleton, so this is the mean over bones and frames)

Extra measures used on data without ground truth (Kinect):

* jitter: mean magnitude of the second difference ``|x_{t+1} - 2 x_t + x_{t-1}|`` over
  joints and frames, in **metres per frame squared** (so it depends on the rate:
  compare methods at the same rate only);
* bone-length coefficient of variation: per bone ``std_t(l) / mean_t(l)``, averaged
  over bones (dimensionless);
* ``gap_mae``: mean joint error over the missing joint-frames only (m).
* ``seam_jitter``: the jitter on given frames (e.g. next to a streaming window
  hand-over) and on all others: a seam shows as a ratio above 1.

NaN samples are ignored everywhere (a metric over no samples is NaN).
"""
from __future__ import annotations

import warnings

import numpy as np

from .robust_stats import nanmedian

__all__ = ["aje", "abe", "jitter", "bone_lengths", "bone_length_cv", "gap_mae", "joint_errors", "seam_jitter",
           "seam_sums", "inferred_bone_asymmetry"]


def _check_pair(pred: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if pred.shape != truth.shape or pred.ndim != 3 or pred.shape[2] != 3:
        raise ValueError(f"expected two (T, J, 3) arrays of equal shape, got {pred.shape} and {truth.shape}")
    return pred, truth


def _nanmean(a: np.ndarray) -> float:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(np.nanmean(a)) if a.size else float("nan")


def joint_errors(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(T, J)`` Euclidean distances d(n~_p^t, n_p^t) in metres."""
    pred, truth = _check_pair(pred, truth)
    return np.linalg.norm(pred - truth, axis=2)


def aje(pred: np.ndarray, truth: np.ndarray) -> float:
    """Average joint error omega (m), Yang et al. Section IV."""
    return _nanmean(joint_errors(pred, truth))


def bone_lengths(positions: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """``(T, B)`` bone lengths l_ij^t (m) for bones ``(B, 2)`` of joint indices."""
    x = np.asarray(positions, dtype=np.float64)
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    return np.linalg.norm(x[:, b[:, 0]] - x[:, b[:, 1]], axis=2)


def abe(pred: np.ndarray, truth: np.ndarray, bones: np.ndarray) -> float:
    """Average bone-length error xi (m), Yang et al. Section IV."""
    pred, truth = _check_pair(pred, truth)
    return _nanmean(np.abs(bone_lengths(truth, bones) - bone_lengths(pred, bones)))


def jitter(positions: np.ndarray) -> float:
    """Mean ``|x_{t+1} - 2 x_t + x_{t-1}|`` over frames and joints (m/frame^2)."""
    x = np.asarray(positions, dtype=np.float64)
    if x.shape[0] < 3:
        return float("nan")
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    return _nanmean(np.linalg.norm(d2, axis=-1))


BONE_CV_MIN_LENGTH_M = 1e-3
"""Bones whose mean length is below this (m) are left out of :func:`bone_length_cv`: a BVH's
zero-length link has no length to vary, and its std / mean is round-off over round-off."""


def bone_length_cv(positions: np.ndarray, bones: np.ndarray, frames: np.ndarray | None = None) -> float:
    """Mean over bones of std_t(l) / mean_t(l); optionally only over ``frames`` ``(T,)`` bool.
    Bones shorter than :data:`BONE_CV_MIN_LENGTH_M` on average do not count (NaN if none is left)."""
    lengths = bone_lengths(positions, bones)
    if frames is not None:
        lengths = lengths[np.asarray(frames, dtype=bool)]
    if lengths.shape[0] < 2:
        return float("nan")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(lengths, axis=0)
        cv = np.nanstd(lengths, axis=0) / mean
    return _nanmean(np.where(mean >= BONE_CV_MIN_LENGTH_M, cv, np.nan))


def inferred_bone_asymmetry(
    positions: np.ndarray, inferred: np.ndarray, bones: np.ndarray, mirror: np.ndarray, min_frames: int = 10
) -> float:
    """Worst relative length difference between an inferred limb's bone and its mirror.

    For each bone whose child joint is *inferred* (``inferred`` ``(T, J)`` bool) in at
    least ``min_frames`` frames and that has a left/right counterpart (``mirror`` ``(B,)``,
    itself for midline bones): its median length over those frames against the
    counterpart's median length over the same frames, ``|l - l_mirror| / l_mirror``.
    Returns the largest over such bones, NaN when there are none. Why: a sensor's guessed limb that
    keeps a length its tracked twin does not have (a seated user's inferred shin
    stretched from 0.385 to 0.53 m) is visibly wrong whatever its smoothness.
    """
    x = np.asarray(positions, dtype=np.float64)
    inf = np.asarray(inferred, dtype=bool)
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    m = np.asarray(mirror, dtype=np.intp)
    if inf.shape != x.shape[:2]:
        raise ValueError(f"inferred must be {x.shape[:2]}, got {inf.shape}")
    if m.shape != (len(b),):
        raise ValueError(f"mirror must be ({len(b)},), got {m.shape}")
    lengths = bone_lengths(x, b)                                   # (T, B)
    child_inf = inf[:, b[:, 1]]                                    # (T, B)
    judged = (child_inf.sum(axis=0) >= min_frames) & (m != np.arange(len(b)))
    own = nanmedian(np.where(child_inf, lengths, np.nan), axis=0)
    twin = nanmedian(np.where(child_inf, lengths[:, m], np.nan), axis=0)  # the mirror, same frames
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.abs(own - twin) / twin
    rel = rel[judged & np.isfinite(rel) & (twin > 0)]
    return float(rel.max()) if rel.size else float("nan")


def mean_move(output: np.ndarray, data: np.ndarray, counted: np.ndarray) -> float:
    """Mean ``|output - data|`` (m) over the ``counted`` ``(T, J)`` joint-frames where both are finite;
    NaN when there are none. Why: how far a method moved the samples it was given (issue 8's
    "tracked joints moved" on real Kinect files, and the same on the paired recordings)."""
    d = np.linalg.norm(np.asarray(output, dtype=np.float64) - np.asarray(data, dtype=np.float64), axis=-1)
    ok = np.asarray(counted, dtype=bool) & np.isfinite(d)
    return float(d[ok].mean()) if ok.any() else float("nan")


def gap_mae(pred: np.ndarray, truth: np.ndarray, missing: np.ndarray) -> float:
    """Mean joint error (m) over the joint-frames flagged in ``missing`` ``(T, J)`` only."""
    err = joint_errors(pred, truth)
    missing = np.asarray(missing, dtype=bool)
    if missing.shape != err.shape:
        raise ValueError(f"missing must be {err.shape}, got {missing.shape}")
    return _nanmean(err[missing])


def seam_sums(d2: np.ndarray, seam: np.ndarray, radius: int | None = None) -> tuple[float, int, float, int]:
    """Partial sums of the seam measure: ``(seam_sum, seam_n, other_sum, other_n)``.

    ``d2`` ``(T, J)``: each joint-frame's second difference (NaN = undefined or not
    scored); ``seam`` ``(T,)`` bool marks frames (the two around each window hand-over).
    ``seam_sum / seam_n`` is the mean over the finite seam joint-frames. ``radius`` None:
    ``other_sum / other_n`` is the mean over all the other finite joint-frames. ``radius``
    r (frames): it is the mean, over the same seam joint-frames, of each one's *local*
    baseline, the same joint's mean over the other frames within r frames (seam
    joint-frames without one are left out of both sums). Why local: where hand-overs are
    closer together (a body's first window, :func:`streamfix.streaming.blending.next_window_end`)
    a global mean would compare that stretch's motion with the rest of the take's.
    """
    d2 = np.asarray(d2, dtype=np.float64)
    seam = np.asarray(seam, dtype=bool)
    if d2.ndim != 2 or seam.shape != (d2.shape[0],):
        raise ValueError(f"expected (T, J) second differences and a (T,) seam mask, got {d2.shape} and {seam.shape}")
    finite = np.isfinite(d2)
    on = finite & seam[:, None]
    off = finite & ~seam[:, None]
    if radius is None:
        return float(d2[on].sum()), int(on.sum()), float(d2[off].sum()), int(off.sum())
    T = d2.shape[0]
    r = max(int(radius), 1)
    zero = np.zeros((1, d2.shape[1]))
    total = np.concatenate([zero, np.cumsum(np.where(off, d2, 0.0), axis=0)])
    count = np.concatenate([zero, np.cumsum(off, axis=0)])
    t = np.arange(T)
    lo, hi = np.maximum(t - r, 0), np.minimum(t + r + 1, T)
    n = count[hi] - count[lo]                                    # (T, J) other frames within r
    base = np.divide(total[hi] - total[lo], n, out=np.zeros_like(d2), where=n > 0)
    use = on & (n > 0)
    return float(d2[use].sum()), int(use.sum()), float(base[use].sum()), int(use.sum())


def seam_jitter(positions: np.ndarray, seam: np.ndarray, radius: int | None = None) -> tuple[float, float]:
    """(mean second difference on the ``seam`` frames, on the others), m/frame^2.

    ``seam`` ``(T,)`` bool marks frames (e.g. the two around each window hand-over); the
    second difference of frame ``t`` is ``|x_{t+1} - 2 x_t + x_{t-1}|`` per joint, defined
    for ``1 <= t <= T - 2`` (the end frames count for neither side); ``radius``: the other
    frames are those within that many frames of each seam frame (:func:`seam_sums`).
    """
    x = np.asarray(positions, dtype=np.float64)
    seam = np.asarray(seam, dtype=bool)
    if x.ndim != 3 or seam.shape != (x.shape[0],):
        raise ValueError(f"expected (T, J, 3) positions and a (T,) seam mask, got {x.shape} and {seam.shape}")
    if x.shape[0] < 3:
        return float("nan"), float("nan")
    d2 = np.linalg.norm(x[2:] - 2.0 * x[1:-1] + x[:-2], axis=-1)  # (T-2, J)
    s_sum, s_n, o_sum, o_n = seam_sums(d2, seam[1:-1], radius)
    return (s_sum / s_n if s_n else float("nan")), (o_sum / o_n if o_n else float("nan"))
