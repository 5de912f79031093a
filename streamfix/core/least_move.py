"""The least a cleaner must move the tracked joints of a recording to meet a jitter and a bone-CV bar.

Why: issue 8 holds the engine's output on real Kinect files to three bars at once: output
jitter at most median+Savitzky-Golay's, bone-length CV at most a tenth of the input's, and
the tracked joints moved on average at most 1.5x what median+Savitzky-Golay moves them.
:mod:`streamfix.core.rigid_bound` bounds the move the bone bar alone asks for, per frame and
without direction; this finds an output that meets the jitter and bone bars together while
moving the counted joints as little as it can, with the whole take known at once (no
causality, no plausibility: only the bars' own formulas). Its move says where the third
bar sits against the other two: when even this output moves more than the bar allows, no
cleaner meets the three together on that recording.

The problem, with ``y`` the output ``(T, J, 3)`` m and ``x`` the input::

    minimise  move(y)  =  mean over counted joint-frames of |y - x|
    subject to  jitter(y) <= jitter_max,   bone_cv(y) <= cv_max

(:func:`streamfix.core.metrics.jitter` and :func:`~streamfix.core.metrics.bone_length_cv`,
on the joint-frames ``observed``) is solved by an augmented Lagrangian, minimised by Adam steps on the exact gradients of
:func:`bar_terms`. It is not convex (bone
lengths), so the answer is the best point found from ``start`` (an output that already
meets the bars, such as the engine's, makes the answer no worse than that output), an
upper bound on the true least move; a start far from it and a start near it landing on
the same value says the optimum is near. Pure arrays in, arrays out.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .interpolate import observed_mask
from .isometry import bone_vectors, incidence_matrix
from .metrics import bone_length_cv, jitter
from .points import point_norms

__all__ = ["LeastMove", "least_move_meeting_bars", "bar_terms"]

SMOOTH_M = 1e-5
"""Distances below this (m) are smoothed (``sqrt(d^2 + SMOOTH_M^2)``) so the move and jitter terms have a gradient at 0."""

LEARNING_RATE_M = (1e-3, 1e-5)
"""First and last step (m) of the gradient steps; the move is an l1-like term, sharp where a
joint is left where it was, which first-order steps of shrinking size cross (L-BFGS stalled at
that kink well above where these steps end, on seated_joints.csv)."""

ADAM_BETAS = (0.9, 0.999)
PENALTY = 10.0
"""Augmented-Lagrangian penalty on the bars' relative violations."""

MULTIPLIER_EVERY = 200
"""Steps between multiplier updates."""


@dataclass
class LeastMove:
    """What :func:`least_move_meeting_bars` found: the output ``positions`` ``(T, J, 3)`` m,
    its mean move of the counted joint-frames (m), jitter (m/frame^2) and bone CV, and
    whether it meets both bars (``feasible``; the move is only a statement about the bars when True)."""

    positions: np.ndarray
    move_m: float
    jitter: float
    bone_cv: float
    feasible: bool


def bar_terms(y: np.ndarray, x: np.ndarray, counted: np.ndarray, observed: np.ndarray, bones: np.ndarray,
              with_gradient: bool = True, incidence: np.ndarray | None = None):
    """``(move, jitter, cv)`` of output ``y`` against input ``x`` (all ``(T, J, 3)`` m) and, with
    ``with_gradient``, their gradients ``(T, J, 3)`` (the same three, in that order).

    The metrics' own definitions on ``observed`` joint-frames (the move on those ``counted`` too): jitter over the second
    differences whose three frames are observed, bone CV over the frames where both ends
    are, each bone's std over mean, averaged over bones seen in at least two frames.
    Distances are smoothed by :data:`SMOOTH_M` (a 10 um change to what the metrics say).
    ``incidence``: :func:`~streamfix.core.isometry.incidence_matrix` of the bones, when the caller keeps one.
    """
    obs = np.asarray(observed, dtype=bool)
    cnt = np.asarray(counted, dtype=bool) & obs
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    eps2 = SMOOTH_M ** 2
    # move: mean |y - x| over counted joint-frames
    d = y - x
    dn = np.sqrt((d * d).sum(axis=2) + eps2)
    n_cnt = max(int(cnt.sum()), 1)
    move = float(dn[cnt].sum() / n_cnt)
    # jitter: mean |y[t+1] - 2 y[t] + y[t-1]| where the three frames are observed
    d2 = y[2:] - 2.0 * y[1:-1] + y[:-2]
    ok2 = obs[2:] & obs[1:-1] & obs[:-2]
    d2n = np.sqrt((d2 * d2).sum(axis=2) + eps2)
    n2 = max(int(ok2.sum()), 1)
    jit = float(d2n[ok2].sum() / n2)
    # bone CV: mean over bones of std_t(l) / mean_t(l) over frames with both ends observed
    u = bone_vectors(y, b)                                   # (T, B, 3)
    ln = np.sqrt((u * u).sum(axis=2) + eps2)                 # (T, B)
    okb = obs[:, b[:, 0]] & obs[:, b[:, 1]]
    nb = okb.sum(axis=0)
    seen = nb >= 2
    nb_safe = np.maximum(nb, 1)
    mean = np.where(okb, ln, 0.0).sum(axis=0) / nb_safe
    dev = np.where(okb, ln - mean, 0.0)
    std = np.sqrt((dev * dev).sum(axis=0) / nb_safe)
    cv_b = np.where(seen, std / np.maximum(mean, 1e-9), 0.0)
    n_bones = max(int(seen.sum()), 1)
    cv = float(cv_b.sum() / n_bones)
    if not with_gradient:
        return move, jit, cv
    g_move = np.where(cnt[..., None], d / dn[..., None], 0.0) / n_cnt
    w2 = np.where(ok2[..., None], d2 / d2n[..., None], 0.0) / n2
    g_jit = np.zeros_like(y)
    g_jit[2:] += w2
    g_jit[1:-1] -= 2.0 * w2
    g_jit[:-2] += w2
    # d cv_b / d l_t = (l_t - m) / (n s m) - s / (n m^2) on the bone's frames
    m_safe = np.maximum(mean, 1e-9)
    s_safe = np.maximum(std, 1e-12)
    dl = (dev / (nb_safe * s_safe * m_safe) - (std / (nb_safe * m_safe ** 2))) * (okb & seen) / n_bones
    gu = (dl / ln)[..., None] * u                            # (T, B, 3)
    if incidence is None:
        incidence = incidence_matrix(b, y.shape[1])
    g_cv = np.matmul(gu.transpose(0, 2, 1), incidence).transpose(0, 2, 1)  # scatter to both ends
    return (move, jit, cv), (g_move, g_jit, g_cv)


def least_move_meeting_bars(
    positions: np.ndarray,
    counted: np.ndarray,
    observed: np.ndarray,
    bones: np.ndarray,
    jitter_max: float,
    cv_max: float,
    start: np.ndarray | None = None,
    margin: float = 0.01,
    steps: int = 12000,
) -> LeastMove:
    """An output of ``positions`` ``(T, J, 3)`` m (finite on ``observed`` ``(T, J)``) with
    jitter at most ``jitter_max`` (m/frame^2) and bone CV at most ``cv_max``, moving the
    ``counted`` ``(T, J)`` joint-frames as little as the solver finds (module doc).

    ``start``: the point to begin from (None: the input itself); ``margin``: the bars are
    aimed at ``(1 - margin)`` of their values, so the answer meets them by the metrics'
    exact formulas; ``steps``: gradient steps. Joint-frames not ``observed`` are left as they are.
    """
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3), got {x.shape}")
    obs = observed_mask(x, observed)
    if not (jitter_max > 0 and cv_max > 0):
        raise ValueError(f"jitter_max and cv_max must be positive, got {jitter_max} and {cv_max}")
    cnt = np.asarray(counted, dtype=bool) & obs
    x0 = np.where(obs[..., None], x, 0.0)
    y = x0.copy() if start is None else np.where(obs[..., None], np.asarray(start, dtype=np.float64), 0.0)
    targets = np.array([jitter_max, cv_max]) * (1.0 - margin)
    scale = max(bar_terms(y, x0, cnt, obs, bones, with_gradient=False)[0], 1e-3)  # the move in the start's units
    lam = np.zeros(2)
    m1 = np.zeros_like(y)
    m2 = np.zeros_like(y)
    free = obs[..., None]
    incidence = incidence_matrix(bones, x.shape[1])
    for k in range(steps):
        (_, jit, cv), (g_move, g_jit, g_cv) = bar_terms(y, x0, cnt, obs, bones, incidence=incidence)
        violation = np.array([jit, cv]) / targets - 1.0
        if k % MULTIPLIER_EVERY == MULTIPLIER_EVERY - 1:
            lam = np.maximum(0.0, lam + PENALTY * violation)
        act = np.maximum(0.0, lam + PENALTY * violation)  # the augmented Lagrangian's active multipliers
        grad = np.where(free, g_move / scale + act[0] / targets[0] * g_jit + act[1] / targets[1] * g_cv, 0.0)
        # Adam, its step shrinking geometrically from LEARNING_RATE_M[0] to [1] metres
        m1 = ADAM_BETAS[0] * m1 + (1.0 - ADAM_BETAS[0]) * grad
        m2 = ADAM_BETAS[1] * m2 + (1.0 - ADAM_BETAS[1]) * grad * grad
        rate = LEARNING_RATE_M[0] * (LEARNING_RATE_M[1] / LEARNING_RATE_M[0]) ** (k / max(steps, 1))
        y -= rate * (m1 / (1.0 - ADAM_BETAS[0] ** (k + 1))) / (np.sqrt(m2 / (1.0 - ADAM_BETAS[1] ** (k + 1))) + 1e-12)
    out = np.where(obs[..., None], y, x)
    y_obs = np.where(obs[..., None], out, np.nan)  # the bars' own formulas decide feasibility
    jit, cv = jitter(y_obs), bone_length_cv(y_obs, bones)
    move = float(point_norms(out - x)[cnt].mean()) if cnt.any() else 0.0
    return LeastMove(out, move, jit, cv, bool(jit <= jitter_max and cv <= cv_max))
