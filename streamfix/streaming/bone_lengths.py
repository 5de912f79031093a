"""A body's bone lengths for its next window, from the last seconds of raw input.

The engine's main thread only files each frame's raw bone lengths into the body's
memory (:func:`record_raw_bones`, a few array operations per hop) and hands the window
job a :class:`LengthSources` snapshot; the estimate itself (two densest modes over up to
``BONE_MEMORY_S`` of samples and the left/right pooling, the costliest step of
scheduling a window) runs where the window is solved (:meth:`LengthSources.resolve`):
in threaded mode on the worker, whose compiled kernels release the GIL, so the live
path is not kept waiting. The result is the same as computing it at scheduling time.

The body's clean output feeds a second memory (:func:`sample_clean_bones`): the median
of its bone lengths, the fallback while the raw estimate is not trusted and the live
path's lengths.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.isometry import bone_lengths_per_frame, length_mode_with_support, symmetric_lengths, thrown_twins
from ..core.points import point_norms
from .bodies import (
    BONE_HISTORY_S,
    BONE_OWN_SUPPORT_S,
    BONE_PEAK_SHARE,
    BONE_SUPPORT_FRAMES,
    BONE_SUPPORT_TOL_M,
    GUESSED_SHARE_POOLED,
    Body,
)

__all__ = ["LengthSources", "length_sources", "record_raw_bones", "raw_history_lengths", "sample_clean_bones"]


def record_raw_bones(body: Body, bones: np.ndarray) -> None:
    """File the bone lengths (m) of the body's raw frames not filed yet into its memory:
    ``raw_bones`` where both ends are tracked, ``raw_bones_seen`` where both are observed
    (inferred samples too); NaN otherwise."""
    win = body.ring.window()
    first = max(body.raw_bones_end, win.start)
    if win.end <= first:
        return
    seg = slice(first - win.start, win.end - win.start)
    pos = win.positions[seg]
    lengths = point_norms(pos[:, bones[:, 1]] - pos[:, bones[:, 0]])
    conf = win.confidence[seg]
    low = np.minimum(conf[:, bones[:, 0]], conf[:, bones[:, 1]])
    rows = np.arange(first, win.end) % len(body.raw_bones)
    body.raw_bones[rows] = np.where(low >= 1.0, lengths, np.nan)
    body.raw_bones_seen[rows] = np.where(low > 0.0, lengths, np.nan)
    body.raw_bones_end = win.end


def raw_history_lengths(
    raw_bones: np.ndarray, raw_bones_seen: np.ndarray, mirror_bones: np.ndarray, rate_hz: float,
    max_length_m: float | None = None,
) -> np.ndarray | None:
    """``(B,)`` densest-mode bone lengths (m) over the remembered raw samples, if well supported.

    ``raw_bones`` / ``raw_bones_seen`` ``(N, B)``: per-frame lengths with both ends tracked /
    observed (NaN = none). Frames where both ends of a bone are *tracked* count; a bone
    with less than ``BONE_OWN_SUPPORT_S`` of them uses its *inferred* samples too, then a
    poorly seen bone borrows its mirror's length
    (:func:`~streamfix.core.isometry.symmetric_lengths`). Trusted only when every bone
    has at least ``BONE_SUPPORT_FRAMES`` samples within ``BONE_SUPPORT_TOL_M`` of its
    mode; otherwise None (the clean-history median or per-window estimate is used).
    Unlike the clean-output median this does not feed back on itself: a wrong early
    estimate baked into the clean output cannot persist. On CMU 131_01 / 131_02 at 30 Hz,
    taking this first brought the streaming clean AJE closer to the offline whole-sequence
    AJE than the clean-output median alone did.
    ``max_length_m``: samples longer than this are no bone's (a person's, measured by a depth
    sensor: :data:`streamfix.core.ray_depth.MAX_BONE_M`) and left out; None keeps every one.
    """
    if max_length_m is not None:
        with np.errstate(invalid="ignore"):
            raw_bones = np.where(raw_bones > max_length_m, np.nan, raw_bones)
            raw_bones_seen = np.where(raw_bones_seen > max_length_m, np.nan, raw_bones_seen)
    est, support = length_mode_with_support(raw_bones, tolerance_m=BONE_SUPPORT_TOL_M)
    own = max(1, int(round(BONE_OWN_SUPPORT_S * rate_hz)))
    thin = support < own
    if thin.any():
        # never a length from a handful of tracked frames: a limb the sensor mostly
        # infers keeps consistent lengths in its inferred samples (seated_joints: the
        # left shin's 7 tracked frames said 0.53 m, its 350 inferred ones 0.385 m)
        est_all, support_all = length_mode_with_support(raw_bones_seen, tolerance_m=BONE_SUPPORT_TOL_M)
        use = thin & (support_all > support)
        est, support = np.where(use, est_all, est), np.where(use, support_all, support)
    # a bone twice as long as its twin, and a quarter metre longer, is no person's: a joint the
    # sensor put at the wall's depth behind it for most of the memory (core/ray_depth.py) left
    # the mode there, which the depth repair and the output's projection would then keep. Taken
    # before the pooling below, which would otherwise average such a mode into its twin's (a
    # shin thrown 1.7 m back for 1.5 s came out far too long, the depth repair then put the ankle there)
    thrown = thrown_twins(est, mirror_bones)
    est, support = np.where(thrown, est[mirror_bones], est), np.where(thrown, support[mirror_bones], support)
    # a mode is a length only if it is a peak: clean samples of a rigid bone pile up
    # within millimetres, corrupted ones spread over decimetres (80 % of coordinates
    # corrupted: 2-5 % of samples near the mode, real sensors 14-90 %)
    seen = np.isfinite(raw_bones_seen).sum(axis=0)
    with np.errstate(invalid="ignore"):
        near = (np.abs(raw_bones_seen - est[None, :]) <= BONE_SUPPORT_TOL_M).sum(axis=0)
    peaked = ~np.isfinite(est) | (near >= BONE_PEAK_SHARE * seen)  # unseen: the mirror's (below)
    peaked = np.where(thrown, peaked[mirror_bones], peaked)  # a thrown bone's twin's peak stands for it
    # a limb the sensor has been guessing shares its lengths with its mirror (see
    # symmetric_lengths): its own samples, however many, are the sensor's guesses
    guessed = seen - np.isfinite(raw_bones).sum(axis=0)
    lo, hi = GUESSED_SHARE_POOLED
    pool = np.clip((guessed / np.maximum(seen, 1) - lo) / (hi - lo), 0.0, 1.0) * (guessed > 0)
    est, support = symmetric_lengths(est, support, mirror_bones, own_support=own, pool=pool)
    if np.isfinite(est).all() and (support >= BONE_SUPPORT_FRAMES).all() and peaked.all():
        return est
    return None


@dataclass
class LengthSources:
    """What a window's bone lengths are estimated from, copied when the window is scheduled.

    ``raw_bones`` / ``raw_bones_seen``: the body's raw-length memory (None: no bones, or
    fixed lengths); ``fallback``: the lengths to use when the raw estimate is not trusted
    (the clean-output median once ``BONE_HISTORY_S`` of it exist, else a re-identified
    body's remembered lengths, else None: the window solver estimates its own, and the
    depth-repair stage judges by the window's provisional lengths, ``core.ray_depth``).
    """

    raw_bones: np.ndarray | None
    raw_bones_seen: np.ndarray | None
    mirror_bones: np.ndarray
    rate_hz: float
    fallback: np.ndarray | None
    max_length_m: float | None = None

    def resolve(self) -> np.ndarray | None:
        """``(B,)`` lengths in metres, or None."""
        if self.raw_bones is not None:
            raw = raw_history_lengths(self.raw_bones, self.raw_bones_seen, self.mirror_bones, self.rate_hz,
                                      self.max_length_m)
            if raw is not None:
                return raw
        return self.fallback


def length_sources(body: Body, bones: np.ndarray, mirror_bones: np.ndarray, rate_hz: float,
                   fixed_lengths: np.ndarray | None, max_length_m: float | None = None) -> LengthSources:
    """What the body's bone lengths come from (resolved where the window is solved).

    ``fixed_lengths`` if configured; else the densest mode of the last ``BONE_MEMORY_S``
    of raw input when well supported (:func:`raw_history_lengths`); else the median over
    the body's last ``BONE_MEMORY_S`` (10 s) of *clean* output (robust: the window solver
    already removed the outliers, while a median over raw corrupted input is biased by
    several cm), once ``BONE_HISTORY_S`` (3 s) of it exist; before that, the lengths
    remembered for a re-identified body, else None (the window solver estimates them
    from its window). Per-window estimates alone were measurably less accurate than the clean
    history once it holds 3 s (CMU 131 at 20 % corruption).
    ``max_length_m``: raw samples longer than this are left out (:func:`raw_history_lengths`).
    """
    if fixed_lengths is not None:
        return LengthSources(None, None, mirror_bones, rate_hz, fixed_lengths)
    need = min(max(1, int(round(BONE_HISTORY_S * rate_hz))), len(body.clean_bones))
    if len(bones) and body.clean_bones_n >= need and body.clean_lengths is not None:
        fallback = body.clean_lengths
    else:
        fallback = body.prior_lengths
    if not len(bones):
        return LengthSources(None, None, mirror_bones, rate_hz, fallback)
    record_raw_bones(body, bones)
    return LengthSources(body.raw_bones.copy(), body.raw_bones_seen.copy(), mirror_bones, rate_hz, fallback,
                         max_length_m)


def sample_clean_bones(body: Body, frames: np.ndarray, bones: np.ndarray, hop: int) -> np.ndarray | None:
    """File clean frames ``frames`` ``(n, J, 3)`` m, oldest first, into the body's clean-length memory.

    Every ``hop`` filed frames the kept frames are measured (one array call) and the median
    over the memory becomes ``body.clean_lengths`` (None while not finite). Returns the
    newest such median when the run completed a hop (for the live path, which keeps only
    the newest lengths), else None. A run of frames gives the same memory and median as
    filing them one by one: the rows a hop's frames go to and the memory the median is
    taken over at the run's last completed hop are the same.
    """
    n0 = body.clean_bones_n
    n1 = n0 + len(frames)
    body.clean_bones_n = n1
    done = n1 - n1 % hop  # frames filed up to the newest completed hop
    if done <= n0:  # no hop completes in this run
        body.clean_pending.extend(frames.copy())  # copies: the emitted frames may be changed by their receiver
        return None
    measured = np.concatenate([np.asarray(body.clean_pending).reshape((-1,) + frames.shape[1:]),
                               frames[: done - n0]])
    body.clean_pending = list(frames[done - n0:].copy())
    cap = len(body.clean_bones)
    measured = measured[-cap:]  # older frames would be overwritten within the run
    body.clean_bones[np.arange(done - len(measured), done) % cap] = bone_lengths_per_frame(measured, bones)
    rows = body.clean_bones[: min(done, cap)]
    est = np.median(rows, axis=0)  # clean output is finite
    body.clean_lengths = est if np.isfinite(est).all() else None
    return est
