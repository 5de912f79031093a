"""Inferred limbs that stopped articulating: a depth sensor's guess for a limb it lost.

Why: when a Kinect loses a limb it keeps reporting it, flagged *inferred*, from its own
guess, and that guess no longer bends: the elbow-down or knee-down part keeps one pose
relative to the joint it hangs from (carried along by the body) or slides off at a
steady speed. Its signature is a joint whose position relative to its parent follows a
straight line in time (a constant offset or a constant drift) to within a few
millimetres for half a second or more while the sensor flags it inferred.

The signature is necessary, not sufficient: a limb the person holds still is a straight
line too. On the shared Kinect v2 recordings the inferred legs of ``seated_joints.csv``
follow a line to 0.7-2.4 mm (median), but so do the *tracked* elbows, wrists, knees and
ankles in 46-72 % of their frames. So a rigid run counts as a guess only while the
limb's left/right twin bends: a person holding still holds both. What remains is a limb
held still while the other moves; the engine replaces such runs with its gap fill
(:mod:`streamfix.streaming.bridging`), and the sensor protocol's ``flagged`` kind and
``tests/test_frozen_limbs.py`` measure what that costs where the guess was right.

:func:`articulation` is the measure, :func:`frozen_inferred` the decision. Arrays:
positions ``(T, J, 3)`` metres, masks ``(T, J)`` bool, ``parents`` ``(J,)`` int (-1 = root).
"""
from __future__ import annotations

from typing import Any

import numpy as np
from scipy import ndimage
from scipy.ndimage import uniform_filter1d

from .interpolate import missing_run_lengths, run_labels
from .points import finite_points, point_norms

__all__ = ["articulation", "frozen_inferred", "frozen_and_rigid", "RIGID_M", "TWIN_BENDS_M", "ARTICULATION_SPAN_S",
           "MIN_FROZEN_S", "MIN_DECIDING_BONE_M"]

RIGID_M = 0.004
"""Articulation (m, RMS residual of the straight-line fit, summed over axes) below which
an inferred joint counts as a frozen guess: above the 0.7-2.4 mm of a real Kinect v2's
inferred legs, below the 10 mm and more (5th percentile) of the sensor protocol's limbs
flagged inferred while moving, sampled with its noise."""

TWIN_BENDS_M = 2 * RIGID_M
"""Articulation (m, median over the run's frames) the left/right twin must reach for a
rigid inferred run to count as a guess: a clear margin above ``RIGID_M``. At a twin just
above ``RIGID_M`` (a seated leg settling after a move, ``seated_joints.csv``) the decision
flipped between overlapping windows, which saw different parts of the settling, and the
released knee swung far between them; the sensor protocol's moving limbs articulate
10 mm and more (5th percentile)."""

ARTICULATION_SPAN_S = 0.5
"""Span (s) of the straight-line fit behind :func:`articulation`."""

MIN_FROZEN_S = 0.5
"""An inferred run shorter than this (s) is left alone: too short to tell from a pause."""

MIN_DECIDING_BONE_M = 0.15
"""Bones shorter than this (m: hands, feet, fingers) do not decide; see :func:`frozen_inferred`."""


def _moving_mean(a: np.ndarray, span: int) -> np.ndarray:
    return uniform_filter1d(a, span, axis=0, mode="nearest")


def articulation(positions: np.ndarray, parents: np.ndarray, span: int, joints: np.ndarray | None = None) -> np.ndarray:
    """``(T, J)`` m: per frame, the RMS residual of a least-squares straight line through
    each joint's position relative to its parent over ``span`` frames centred on the frame
    (summed over the three axes). 0 for a limb frozen or drifting at a constant velocity
    relative to its parent; NaN for roots and where the joint or its parent is NaN.

    Computed from running moments (``uniform_filter1d``), so the cost does not grow with
    ``span``; near the ends the span is padded by repeating the end frames. ``joints``
    (indices): compute only these columns, the others are NaN.
    """
    x = np.asarray(positions, dtype=np.float64)
    par = np.asarray(parents, dtype=np.intp)
    T, J = x.shape[:2]
    if joints is not None:
        cols = np.asarray(joints, dtype=np.intp)
        full = np.full((T, J), np.nan)
        if len(cols):
            sub = np.concatenate([x[:, cols], x[:, np.maximum(par[cols], 0)]], axis=1)
            sub_par = np.where(par[cols] >= 0, np.arange(len(cols)) + len(cols), -1)
            full[:, cols] = articulation(sub, np.concatenate([sub_par, np.full(len(cols), -1)]), span)[:, : len(cols)]
        return full
    span = max(3, int(span))
    rel = x - x[:, np.maximum(par, 0)]
    bad = ~finite_points(rel) | (par < 0)[None, :]
    rel = np.where(bad[..., None], 0.0, rel)
    t = (np.arange(T, dtype=np.float64) - 0.5 * (T - 1))[:, None, None]  # centred: better conditioned
    m_t = _moving_mean(np.broadcast_to(t, (T, 1, 1)).copy(), span)
    m_tt = _moving_mean(t * t, span)
    m_r = _moving_mean(rel, span)
    m_tr = _moving_mean(t * rel, span)
    m_rr = _moving_mean(rel * rel, span)
    var_t = np.maximum(m_tt - m_t * m_t, 1e-12)
    cov = m_tr - m_t * m_r
    resid = np.maximum(m_rr - m_r * m_r - cov * cov / var_t, 0.0)
    out = np.sqrt(resid.sum(axis=2))
    # a NaN anywhere in a frame's span makes its value meaningless
    bad_near = _moving_mean(bad.astype(np.float64), span) > 0
    out[bad_near] = np.nan
    return out


def _run_medians(values: np.ndarray, label: np.ndarray, n_runs: int) -> np.ndarray:
    """``(n_runs,)``: the median of the finite ``values`` under each label 1..n_runs
    (``values``, ``label`` of one shape, 0 = no run); NaN for a run with none."""
    ok = np.isfinite(values) & (label > 0)
    counts = np.bincount(label[ok], minlength=n_runs + 1)[1:]
    med = np.full(n_runs, np.nan)
    idx = np.flatnonzero(counts) + 1
    if len(idx):
        med[idx - 1] = ndimage.median(np.where(ok, values, 0.0), labels=np.where(ok, label, 0), index=idx)
    return med


def frozen_inferred(
    positions: np.ndarray,
    inferred: np.ndarray,
    parents: np.ndarray,
    limb_joints: np.ndarray,
    rate_hz: float,
    **options: Any,
) -> np.ndarray:
    """``(T, J)`` bool: the frozen mask of :func:`frozen_and_rigid` alone (``options``: its
    keyword settings)."""
    return frozen_and_rigid(positions, inferred, parents, limb_joints, rate_hz, **options)[0]


def frozen_and_rigid(
    positions: np.ndarray,
    inferred: np.ndarray,
    parents: np.ndarray,
    limb_joints: np.ndarray,
    rate_hz: float,
    *,
    rigid_m: float = RIGID_M,
    span_s: float = ARTICULATION_SPAN_S,
    min_run_s: float = MIN_FROZEN_S,
    min_bone_m: float = MIN_DECIDING_BONE_M,
    mirror: np.ndarray | None = None,
    twin_bends_m: float = TWIN_BENDS_M,
) -> tuple[np.ndarray, np.ndarray]:
    """``(frozen, rigid)`` ``(T, J)`` bool. ``frozen``: inferred samples of limb joints that
    belong to a frozen guess; ``rigid``: the same decision without the twin test (the runs
    that are rigid whatever the twin does), from the same articulation measure: the
    streaming release needs both (streaming/frozen_release.py).

    A sample is frozen when it lies in a run of inferred samples of its joint at least
    ``min_run_s`` long, its joint is one of ``limb_joints`` (``(J,)`` bool: the joints
    below a limb's root, whose position relative to their parent changes as the person
    moves), and the joint's :func:`articulation` over ``span_s`` stays below ``rigid_m``
    across the run's frames (one decision per run, taken on the median over the run's
    interior, the frames whose span lies inside the run, or over all its frames when it
    has none; so a frozen limb is replaced as one stretch, not frame by frame).

    Only joints on a bone of at least ``min_bone_m`` (mean length in the window: elbows,
    wrists, knees, ankles) decide; the joints on short bones below them (hands, hand tips,
    thumbs, feet) are frozen where they are inferred and their parent is frozen. On a
    short bone the sensor's noise is most of the articulation, and a hand the sensor
    stopped bending on a tracked wrist is a few centimetres off at most.

    ``mirror`` ``(J,)`` (each joint's left/right twin; None: no such test): a run is
    frozen only if the twin bends (articulation at least ``twin_bends_m`` over the same
    frames, median). A limb still beside a still twin is a person holding still (a
    seated user's legs); beside a moving twin, the sensor's guess. A twin without a
    measure (missing) does not stop the decision.
    """
    x = np.asarray(positions, dtype=np.float64)
    inf = np.asarray(inferred, dtype=bool) & finite_points(x)
    limbs = np.asarray(limb_joints, dtype=bool)
    T, J = inf.shape
    out = np.zeros_like(inf)
    rigid = np.zeros_like(inf)
    min_run = max(2, int(round(min_run_s * rate_hz)))
    cand = inf & limbs[None, :] & (missing_run_lengths(~inf) >= min_run)
    if not cand.any():
        return out, rigid
    par = np.asarray(parents, dtype=np.intp)
    rel = point_norms(x - x[:, np.maximum(par, 0)])
    fin = np.isfinite(rel)
    bone = np.where(fin, rel, 0.0).sum(axis=0) / np.maximum(fin.sum(axis=0), 1)  # mean length (m)
    deciding = bone >= min_bone_m
    runs = (cand & deciding[None, :]).T  # (J, T)
    if not runs.any():  # the short bones below follow a frozen parent only
        return out, rigid
    cols = np.flatnonzero(runs.any(axis=1))
    if mirror is not None:
        cols = np.union1d(cols, np.asarray(mirror, dtype=np.intp)[cols])
    art = articulation(x, par, int(round(span_s * rate_hz)), joints=cols)
    # one label per (joint, run) of candidate samples; a run is frozen when the median
    # articulation over its frames is below rigid_m
    label = run_labels(runs.T).T  # (J, T)
    n_runs = int(label.max())
    if n_runs:
        # decided on the run's interior, the frames whose whole span lies in the run: at
        # its ends the span reaches the moving limb before and after the freeze, and in a
        # run only a little longer than the span those ends are most of its frames
        half = int(round(span_s * rate_hz)) // 2
        interior = ndimage.binary_erosion(runs, structure=np.ones((1, 2 * half + 1), dtype=bool), border_value=1)
        med = _run_medians(np.where(interior, art.T, np.nan), label, n_runs)
        whole = _run_medians(art.T, label, n_runs)
        med = np.where(np.isfinite(med), med, whole)
        frozen_run = np.concatenate([[False], med < rigid_m])  # NaN (no measure): not frozen
        rigid |= frozen_run[label].T
        if mirror is not None:
            # the same frames of the mirror joint: a limb held still beside a still twin is a
            # person holding still; beside a moving twin, the sensor's guess
            twin_med = _run_medians(art[:, np.asarray(mirror, dtype=np.intp)].T, label, n_runs)
            frozen_run[1:] &= ~(twin_med < twin_bends_m)  # NaN (twin not measured): no objection
        out |= frozen_run[label].T
    followers = np.flatnonzero(limbs & ~deciding & (par >= 0))
    for mask in (out, rigid):
        for _ in range(len(followers)):  # parents first, whatever the joint order (chains are short)
            new = inf[:, followers] & mask[:, par[followers]] & ~mask[:, followers]
            if not new.any():
                break
            mask[:, followers] |= new
    return out, rigid

