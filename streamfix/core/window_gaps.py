"""Stage 4 of the window cleaner, around the solver: short gaps filled in time, open gaps bounded.

Gaps of a few frames (a dropped frame, a joint lost for 1/10 s) are filled by the local
quadratic across them when they are the window's only ones (:func:`fill_short_gaps`), and
closed gaps up to half a second by each joint's cubic spline, which the solver then takes as
data (:func:`spline_closed_gaps`), instead of the window's low-rank solve; a gap still open at
the window's newest frames, which has no far end, is kept near the joint's last pose
(:func:`limit_open_gaps`). :mod:`streamfix.core.pipeline` runs all three.
"""
from __future__ import annotations

import numpy as np

from .excursion import EXCURSION_HORIZON_S, anchor_reference, limit_excursion, parents_from_bones
from .interpolate import continuity_baseline, interpolate_spline, missing_run_lengths, neighbour_observations
from .local_poly import fit_local_quadratic

__all__ = ["fill_short_gaps", "spline_closed_gaps", "limit_open_gaps"]


def fill_short_gaps(positions: np.ndarray, observed: np.ndarray, max_gap_frames: int) -> np.ndarray:
    """Fill gaps of at most ``max_gap_frames`` frames by the weighted local quadratic across them.

    ``positions`` ``(T, J, 3)`` m (values at missing joint-frames ignored), ``observed``
    ``(T, J)``. A gap with samples on both sides takes the local quadratic through its
    neighbours (half-width ``max_gap_frames + 1``: a full gap still has samples on both
    sides of the kernel); one open at the window's edge holds the nearest sample. Why: the
    gaps a stream has most often are single dropped frames the engine synthesised, every
    joint missing for 1/30 s; solving the whole window's low-rank model for them was a
    large share of a streamfix clean of a Kinect recording, and across one or two frames
    the neighbours' curvature says more than the other joints do.
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    n_frames = x.shape[0]
    w = np.repeat(obs.astype(np.float64), 3, axis=1)
    y = np.where(w > 0, x.reshape(n_frames, -1), 0.0)
    fit, _ = fit_local_quadratic(y, w, max(2, int(max_gap_frames) + 1))
    held, prev, nxt = continuity_baseline(x, obs)  # hold at an open edge
    inside = (prev >= 0) & (nxt < n_frames)
    out = np.where(inside[..., None], fit.reshape(x.shape), held)
    out[(prev < 0) & (nxt >= n_frames)] = np.nan  # never observed in the window
    return np.where(obs[..., None], x, out)


def spline_closed_gaps(positions: np.ndarray, observed: np.ndarray,
                       max_gap_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """``(positions (T, J, 3) m, filled (T, J) bool)``: each gap of at most ``max_gap_frames``
    frames with samples on both sides filled by the joint's cubic spline through its samples
    (:func:`streamfix.core.interpolate.interpolate_spline`); every other missing sample stays NaN.

    Why: over a fraction of a second time knows a limb better than the window's low-rank
    model, which put a forearm and hand lost for 4 frames of a fast swing at their mean pose,
    far off (``tests/test_short_gaps_and_blackouts.py``)."""
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    prev, nxt = neighbour_observations(obs)
    filled = ~obs & (missing_run_lengths(obs) <= max_gap_frames) & (prev >= 0) & (nxt < obs.shape[0])
    out = np.where(obs[..., None], x, np.nan)
    if filled.any():
        cols = filled.any(axis=0)  # only the joints with such a gap
        spline = interpolate_spline(x[:, cols], obs[:, cols])[0]
        out[:, cols] = np.where(filled[:, cols, None], spline, out[:, cols])
    return out, filled


def limit_open_gaps(filled: np.ndarray, obs: np.ndarray, bones: np.ndarray, rate_hz: float,
                     gain: float, ramp_s: float) -> np.ndarray:
    """``filled`` ``(T, J, 3)`` m with each gap still open at the window's end kept within
    ``gain`` times the joint's range of motion over ``EXCURSION_HORIZON_S`` (1 s) from its
    last observed pose, relative to the limb's anchor, a bound that grows from 0 over the
    gap's first ``ramp_s`` seconds (:func:`streamfix.core.excursion.limit_excursion`).

    Why: with no far end, the low-rank solve places a joint that has just vanished from
    the other joints alone, and that placement is not tied to where the joint was a frame
    before: an arm lost at a walking body's newest frames came out far from where it
    had been one frame earlier (CMU 131_01, ``tests/test_open_gaps.py``), and the streaming
    engine's clean output (0.5 s lookahead) blends those newest frames in. Closed gaps are
    the boundary correction's.
    """
    prev, nxt = neighbour_observations(obs)
    open_run = ~obs & (prev >= 0) & (nxt == obs.shape[0])  # seen before, not after
    if not open_run.any():
        return filled
    n_joints = obs.shape[1]
    ref = anchor_reference(filled, obs, parents_from_bones(bones, n_joints)) if len(bones) else None
    horizon = max(1, int(round(EXCURSION_HORIZON_S * rate_hz)))
    return limit_excursion(filled, obs, open_run, horizon, gain=gain, reference=ref,
                           ramp=max(1, int(round(ramp_s * rate_hz))))
