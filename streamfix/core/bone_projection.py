"""Stage 5 of the window cleaner: every bone pulled to its length, the error taken by who is least sure.

Position-based dynamics (:func:`project_bone_lengths_pbd`, numpy reference of the compiled
:func:`streamfix.core.kernels.project_bone_lengths_pbd`) splits each bone's length error
between its ends by inverse mass: confidence (:func:`projection_inverse_mass`), noise
(:func:`joint_noise_scale`) and lost tracking (:func:`tracking_failures`) decide the
shares; the correction on noisy joints is smoothed in time (:func:`smooth_projection`).
:func:`project_bone_lengths` is the Gauss-Newton step of Yang et al.'s Eq. (20) it was
measured against. See :mod:`streamfix.core.pipeline` (stage 5) for why each part is there.

Arrays: positions ``(T, J, 3)`` metres, bones ``(B, 2)`` joint indices, lengths ``(B,)`` m
(or ``(T, B)`` per-frame targets), confidence ``(T, J)`` in [0, 1].
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .interpolate import missing_run_lengths
from .isometry import gauss_newton_step, incidence_matrix
from .local_poly import fit_local_quadratic
from .points import finite_points
from .robust_stats import nanmedian

__all__ = ["project_bone_lengths", "project_bone_lengths_pbd", "project_pbd", "joint_noise_scale", "noise_share",
           "tracking_failures", "projection_inverse_mass", "smooth_projection"]


def project_bone_lengths(
    positions: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray,
    steps: int = 4,
    gamma: float = 1e4,
) -> np.ndarray:
    """Pull bones toward ``bone_lengths`` (m) by Gauss-Newton on Eq. (20) with Z2 = 0.

    Each step minimises the linearised ``gamma/2 E_iso(N) + 1/2 ||N - A||^2`` around the
    current N, anchored at the input A: a proximal projection onto constant bone
    lengths (large gamma = nearly exact lengths, small moves).
    """
    A = np.asarray(positions, dtype=np.float64)
    if len(bones) == 0 or steps <= 0:
        return A.copy()
    finite = finite_points(A)
    if not finite.all():
        return A.copy()  # never invent data for joints that are still missing
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    inc = incidence_matrix(b, A.shape[1])
    N = A.copy()
    zero = np.zeros_like(A)
    for _ in range(steps):
        N = gauss_newton_step(N, A, zero, 1.0, gamma, b, bone_lengths, inc)
    return N


def project_bone_lengths_pbd(
    positions: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray,
    iterations: int = 20,
    inverse_mass: np.ndarray | None = None,
) -> np.ndarray:
    """Bone-length projection by Jacobi constraint iterations (position-based dynamics).

    Per bone (i, j) with current vector u = n_i - n_j and target length l (``bone_lengths``
    ``(B,)``, or ``(T, B)`` for a target per frame: :func:`streamfix.core.length_tolerance.length_targets`),
    the length error (|u| - l) is split between its two ends along u in proportion to their
    inverse masses ``inverse_mass`` ``(T, J)`` (a low-confidence joint moves more);
    each joint moves by the mean of its bones' corrections. Vectorised over frames and
    bones; unconditionally stable (every step shortens each violated constraint).
    """
    x = np.asarray(positions, dtype=np.float64).copy()
    i, j, target, share_i, degree = kernels.pbd_constraints(x.shape, bones, bone_lengths, inverse_mass)
    if len(i) == 0 or iterations <= 0 or not np.isfinite(x).all():
        return x
    n_frames, n_joints, _ = x.shape
    rows = np.arange(len(i))
    P = np.zeros((len(i), n_joints))
    Q = np.zeros((len(i), n_joints))
    P[rows, i] = 1.0
    Q[rows, j] = 1.0
    P /= np.maximum(degree, 1.0)[None, :]  # scatter to joints and average over their bones
    Q /= np.maximum(degree, 1.0)[None, :]
    # joint-major layout (J, 3, T): each iteration is two row gathers, norms from three
    # contiguous (B, T) planes, and one matrix product scattering both bones' ends,
    # C = [-P^T, Q^T] (J, 2B)
    n_bones = len(i)
    C = np.concatenate([-P.T, Q.T], axis=1)
    si = share_i.T[:, None, :]                                    # (B, 1, T)
    xt = np.ascontiguousarray(x.transpose(1, 2, 0))               # (J, 3, T)
    for _ in range(iterations):
        u = xt[i] - xt[j]                                         # (B, 3, T)
        sq = u * u
        norm = np.sqrt(sq[:, 0] + sq[:, 1] + sq[:, 2])            # (B, T)
        err = (norm - target) / np.maximum(norm, 1e-9)
        err[norm <= 1e-9] = 0.0
        corr = u * err[:, None, :]                                # the full length error along u
        corr_i = corr * si
        V = np.concatenate([corr_i, corr - corr_i])               # i's share, then j's
        xt += (C @ V.reshape(2 * n_bones, 3 * n_frames)).reshape(n_joints, 3, n_frames)
    return np.ascontiguousarray(xt.transpose(2, 0, 1))



def joint_noise_scale(observed_positions: np.ndarray, estimate: np.ndarray, inlier: np.ndarray) -> np.ndarray:
    """``(J,)`` robust scale (m) of each joint's inlier coordinates about ``estimate`` ``(T, J, 3)``.

    1.4826 x the median absolute residual over the window's frames and axes; 0 for a
    joint with no inlier. Exact samples (mocap, the paper protocol's uncorrupted
    entries) give 0; on Kinect v2 a thumb or hand several times a shoulder's.
    """
    resid = np.abs(np.where(inlier, np.asarray(observed_positions, dtype=np.float64) - estimate, np.nan))
    per_joint = resid.transpose(1, 0, 2).reshape(resid.shape[1], -1)
    scale = 1.4826 * nanmedian(per_joint, axis=1)
    return np.nan_to_num(scale, nan=0.0)


def noise_share(noise_m: np.ndarray, noise_floor_m: float | None) -> np.ndarray:
    """``(J,)`` in [0, 1): ``s^2 / (s^2 + floor^2)``, how much of a joint's sample is noise (0 = exact)."""
    s2 = np.asarray(noise_m, dtype=np.float64) ** 2
    if noise_floor_m is None:
        return np.zeros_like(s2)
    return s2 / (s2 + float(noise_floor_m) ** 2)


def tracking_failures(flagged: np.ndarray, rate_hz: float, min_s: float | None) -> np.ndarray:
    """``(T, J)`` bool: flagged samples in runs of at least ``min_s`` seconds (at ``rate_hz``;
    None = none): a sensor that lost the joint for that long, not a spike or a jittery sample.

    Why: such a run's values are the temporal fit's guess, not a measurement, so the bone
    projection moves it as it moves a missing joint (confidence 0) and leaves its tracked
    neighbour where the sensor put it. On the KERAAL take, the arms' failed runs had made
    the projection drag the top of the spine (SpineShoulder) and the elbows, which the
    sensor had right. Shorter runs keep their confidence: on ``serve``'s schedule, where
    isolated flags are common at the window's newest frames, treating every flag so added
    output jitter (``benchmarks/bench_paired.py``'s jitter column).
    """
    f = np.asarray(flagged, dtype=bool)
    if min_s is None or not f.any():
        return np.zeros_like(f)
    min_frames = max(1, int(round(min_s * rate_hz)))
    return missing_run_lengths(~f) >= min_frames


def projection_inverse_mass(
    confidence: np.ndarray,
    observed: np.ndarray,
    noise_m: np.ndarray,
    noise_floor_m: float | None,
    noisy_ratio: float = 2.0,
) -> np.ndarray:
    """``(T, J)`` inverse masses for :func:`project_bone_lengths_pbd`: who takes a bone's length error.

    Confidence: tracked 1, inferred (0.5) 2x, missing 4x. Noise: a joint clearly noisier
    than the body's typical joint (scale ``s_j`` above ``noisy_ratio`` x the median
    joint's plus ``noise_floor_m``; :func:`joint_noise_scale`) moves
    ``(s_j / that level)^2`` times more: the weighted least-squares split of a length
    error between two measurements of unequal variance. Why: on Kinect v2 a bone's
    length error comes from its noisier end (thumb, hand tip, hand); split evenly, the
    correction carried the hand's jitter into the wrist, shoulders and spine (on
    Ges04_comehere.csv the projection made the shoulders jitter far more). Joints of similar
    noise keep equal shares: weighting them by estimated scales only moved corrections
    at random (measured on the sensor protocol, whose noise is the same on every joint).
    """
    conf_mass = 1.0 / np.maximum(np.where(observed, confidence, 0.0), 0.25)
    s = np.asarray(noise_m, dtype=np.float64)
    if noise_floor_m is None or not s.size:
        return conf_mass
    level = noisy_ratio * float(np.median(s)) + noise_floor_m
    return conf_mass * np.maximum(1.0, (s / level) ** 2)[None, :]


def smooth_projection(
    estimate: np.ndarray, projected: np.ndarray, share: np.ndarray, rate_hz: float, span_s: float,
    exact: np.ndarray | None = None,
) -> np.ndarray:
    """``projected`` with the correction ``projected - estimate`` smoothed over time on noisy joints.

    The correction is replaced by its zero-lag local quadratic over ``span_s`` seconds
    in proportion to each joint's noise ``share`` ``(J,)`` (:func:`noise_share`). Why: on
    a noisy short bone (a Kinect hand, thumb or foot) the bone's direction jitters, and a
    steady length correction applied along it every frame turns that into position
    jitter (Ges04_comehere.csv: the projected output jittered more than median +
    Savitzky-Golay, the unprojected one less). Smoothed, a persistent length error is
    still removed and frame-to-frame length noise is left as it was. Exact joints
    (share 0: mocap) keep the exact projection, and so do the samples ``exact`` ``(T, J)``
    marks (filled or replaced, no sensor reading behind them): their direction carries
    no sensor jitter, and a smoothed correction would leave a short fill (a thumb's
    4-frame spike replaced) at the wrong length.
    """
    h = int(round(span_s * rate_hz / 2))
    if h < 2 or not np.any(share > 0):
        return projected
    n_frames = estimate.shape[0]
    corr = (projected - estimate).reshape(n_frames, -1)
    smooth, _ = fit_local_quadratic(corr, np.ones_like(corr), h)
    a = np.repeat(np.asarray(share, dtype=np.float64), 3)[None, :]
    if exact is not None and exact.any():
        a = np.where(np.repeat(exact, 3, axis=1), 0.0, a)
    return estimate + (corr + a * (smooth - corr)).reshape(estimate.shape)


def project_pbd(positions, bones, bone_lengths, iterations, inverse_mass):
    """:func:`project_bone_lengths_pbd`, compiled when :data:`streamfix.core.kernels.COMPILED` (same math)."""
    project = kernels.project_bone_lengths_pbd if kernels.COMPILED else project_bone_lengths_pbd
    return project(positions, bones, bone_lengths, iterations, inverse_mass)
