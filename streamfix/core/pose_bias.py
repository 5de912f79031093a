"""Pose-dependent sensor bias: a learned correction from a depth sensor's joints toward the joint centres.

Why: a depth sensor's joint is not the joint centre, and the difference changes with the
pose: Kinect v1 places the knee and the ankle differently as the leg folds in a squat, the
elbow and the wrist as the arm rises. That error is slow (below 3 Hz, the band the paired
benchmark calls ``<3 Hz``), so no smoother removes it; it is consistent across people, so
recordings made with the sensor and optical motion capture at once can measure it.

The model, per corrected joint ``k`` and frame ``t`` (metres, in the body's frame)::

    e_k(t) = (f(t) - mu) W_k

* the body frame ``R(t)``: x from the left to the right shoulder, y up the trunk (pelvis
  to neck, made orthogonal to x), z = x cross y;
* ``f(t)``: the unit direction of each limb segment in that frame and, within each group of
  segments (the arms and head, the legs), the products of those coordinates: a quadratic in
  the limbs' directions (the error of a knee depends on how the thigh and the shank fold
  together, not on either alone);
* with ``sensor_direction``, one more direction in every group: from the trunk (midway
  between pelvis and neck) towards the sensor, which sits at the origin of the camera-space
  coordinates a depth sensor reports. A depth sensor sees each limb from one side and puts
  the joint behind the surface it sees, so where it puts an elbow depends on how the arm is
  turned towards it, not only on how the arm is bent. The limbs' directions alone cannot
  see that: the body frame turns and leans with the trunk, so a body turned or bent towards
  the camera shares the correction of one standing square to it;
* ``W`` by ridge regression of every training frame's error on its features, both with
  their means over all training frames removed: the average offset, how a sensor's joint
  sits on average from a marker-based joint centre, is a matter of definition and is left
  alone; what changes with the pose, within a take and from one take to the next, is
  learned. ``mu`` is the training features' mean, so the correction averages to zero over
  the training poses. (Fitting within takes only, each take's means removed, learns the
  same slopes from less: it leaves between-take pose differences to extrapolation, and on
  held-out people that moved joints several centimetres, worsening the raw error.)

The correction is ``R(t)^T e(t)``. Joints the model does not correct follow a corrected
one (a weighted sum, ``follow``), so that a Kinect Chest moves with the Neck. What a
stream emits (:func:`remove_pose_bias`) is the corrected frame put back on its own bone
lengths, the shift smoothed along the frames.

Safety, for poses the training never saw: the correction fades to zero with the distance
of ``f``'s linear part to the nearest of ``centres`` (k-means of the training poses),
from the training distances' ``FADE_START_QUANTILE`` to ``FADE_END_FACTOR`` times their
largest, and each joint's correction is clipped to the largest the training poses gave.
A frame missing a joint the features need is not corrected. The direction towards the
sensor assumes camera space: it weighs ``SENSOR_FAMILIARITY_WEIGHT`` times a limb direction
in that distance, so a body seen from a side the training never had (coordinates whose
origin is not the sensor) fades, and a trunk within ``MIN_SENSOR_DISTANCE_M`` of the origin
(a take re-centred on the body) is not corrected at all.

Arrays in, arrays out: fitting (:func:`fit_pose_bias`) and applying
(:func:`remove_pose_bias`) are pure; files are :mod:`streamfix.io.pose_bias_model`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bone_projection import project_pbd
from .filters import exponential_smoothing

__all__ = [
    "PoseBiasModel",
    "body_frames",
    "pose_features",
    "feature_groups",
    "towards_sensor",
    "pose_bias",
    "familiarity",
    "remove_pose_bias",
    "PROJECTION_ITERATIONS",
    "fit_pose_bias",
    "body_frame_errors",
    "FADE_START_QUANTILE",
    "CORRECTION_TIME_CONSTANT_S",
    "correction_gain",
    "FADE_END_FACTOR",
    "SENSOR_FAMILIARITY_WEIGHT",
    "MIN_SENSOR_DISTANCE_M",
]

# The correction is estimated from each frame's pose, which carries the sensor's frame-to-frame
# noise; the bias itself is slow (below 3 Hz). A stream smooths the estimate with a one-pole
# low-pass of this time constant (:func:`correction_gain`): unsmoothed, the correction took
# `serve`'s output past the paired benchmark's jitter bar on UI-PRMD; smoothed, the jitter is
# close to the uncorrected output's at the same error (benchmarks/results/paired.md).
CORRECTION_TIME_CONSTANT_S = 0.05
PROJECTION_ITERATIONS = 40  # constraint iterations putting a corrected frame back on its bone lengths
FADE_START_QUANTILE = 0.95  # the correction starts to fade beyond this share of the training poses' distances
FADE_END_FACTOR = 1.0  # and is zero at this multiple of the largest training distance
CLIP_QUANTILE = 0.999  # each joint's correction is clipped to this quantile of the training corrections
# The direction towards the sensor is one 3-vector among the limbs' many in the familiarity distance; weighted
# this much, a body seen from a side the training never saw it from fades the correction. Unweighted, a held-out
# UI-PRMD person with the coordinate origin moved behind them (a frame that is not the sensor's) kept most of
# the correction and ended further from Vicon than without it (tests/test_pose_bias.py holds that case); the
# held-out people's own scores are no worse for the weight (the model card's leave-one-subject-out table)
SENSOR_FAMILIARITY_WEIGHT = 5.0
MIN_SENSOR_DISTANCE_M = 0.5  # a trunk nearer the origin than this: the coordinates are not a sensor's camera space


@dataclass(frozen=True)
class PoseBiasModel:
    """A fitted pose-dependent bias model for one joint layout (see the module doc).

    ``frame_joints``: (left shoulder, right shoulder, pelvis, neck), the body frame.
    ``groups``: segments ``(parent, child)`` per group; the products are within a group.
    ``corrected``: joints whose bias is modelled; ``weights`` (n_features, 3 x n_corrected).
    ``follow``: (n_joints, n_corrected), each layout joint's correction as a weighted sum
    of the corrected joints' (identity rows for the corrected joints themselves).
    """

    skeleton: str
    joint_names: tuple[str, ...]
    frame_joints: tuple[str, str, str, str]
    groups: tuple[tuple[tuple[str, str], ...], ...]
    corrected: tuple[str, ...]
    feature_mean: np.ndarray  # (F,)
    weights: np.ndarray  # (F, 3K) metres per unit feature
    follow: np.ndarray  # (J, K)
    centres: np.ndarray  # (C, L) k-means centres of the training poses' linear features
    fade_start: float  # distance to the nearest centre where fading begins
    fade_end: float  # distance where the correction is zero
    max_correction_m: np.ndarray  # (K,) clip per corrected joint, metres
    ridge: float = 0.0
    training_subjects: tuple[str, ...] = ()  # the people it was fitted on (an evaluation never scores them with it)
    sensor_direction: bool = False  # the direction towards the sensor is one more direction in every group


def correction_gain(rate_hz: float, time_constant_s: float = CORRECTION_TIME_CONSTANT_S) -> float:
    """One-pole gain ``1 - exp(-1 / (rate_hz * time_constant_s))`` (0.49 at 30 Hz) for smoothing the correction."""
    return float(1.0 - np.exp(-1.0 / (float(rate_hz) * time_constant_s)))


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def body_frames(positions: np.ndarray, frame_idx: tuple[int, int, int, int]) -> np.ndarray:
    """(T, 3, 3) rotation per frame whose rows are the body's x, y, z axes in world coordinates."""
    ls, rs, pelvis, neck = frame_idx
    x = _unit(positions[:, rs] - positions[:, ls])
    up = positions[:, neck] - positions[:, pelvis]
    y = _unit(up - np.einsum("ti,ti->t", up, x)[:, None] * x)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def _segment_index(names: tuple[str, ...], groups) -> list[np.ndarray]:
    return [np.array([[names.index(a), names.index(b)] for a, b in g]) for g in groups]


def towards_sensor(positions: np.ndarray, frames: np.ndarray, frame_idx: tuple[int, int, int, int]) -> np.ndarray:
    """(T, 3) unit direction from the trunk (midway between pelvis and neck) to the coordinate origin,
    where a depth sensor's camera-space coordinates put the sensor, in each frame's body frame.

    NaN (the frame is not corrected) where the trunk is nearer the origin than
    ``MIN_SENSOR_DISTANCE_M``: no depth sensor tracks a body that close, so the coordinates are
    not its camera space (a take re-centred on the body, say) and the direction means nothing."""
    _, _, pelvis, neck = frame_idx
    to_origin = -0.5 * (positions[:, pelvis] + positions[:, neck])
    dist = np.linalg.norm(to_origin, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(dist >= MIN_SENSOR_DISTANCE_M, to_origin / dist, np.nan)
    return np.einsum("tij,tj->ti", frames, unit)


def _features(positions: np.ndarray, frames: np.ndarray, segments: list[np.ndarray],
              sensor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(linear (T, L), full (T, F)): segment directions in the body frame, then their within-group products.

    ``sensor`` (T, 3) (:func:`towards_sensor`), if given, is one more direction in every group and
    ends the linear features (the familiarity of a pose includes where the sensor sees it from)."""
    linear, full = [], []
    for seg in segments:
        d = _unit(positions[:, seg[:, 1]] - positions[:, seg[:, 0]])  # (T, S, 3) world
        f = np.einsum("tij,tsj->tsi", frames, d).reshape(len(positions), -1)  # body-frame coordinates
        linear.append(f)
        if sensor is not None:
            f = np.concatenate([f, sensor], axis=1)
        iu = np.triu_indices(f.shape[1])
        full += [f, f[:, iu[0]] * f[:, iu[1]]]
    if sensor is not None:
        linear.append(SENSOR_FAMILIARITY_WEIGHT * sensor)
    return np.concatenate(linear, axis=1), np.concatenate(full, axis=1)


def _all_features(positions: np.ndarray, names: tuple[str, ...], frame_joints, groups,
                  sensor_direction: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    frame_idx = tuple(names.index(n) for n in frame_joints)
    frames = body_frames(positions, frame_idx)
    sensor = towards_sensor(positions, frames, frame_idx) if sensor_direction else None
    linear, full = _features(positions, frames, _segment_index(names, groups), sensor)
    return frames, linear, full


def pose_features(positions: np.ndarray, model: PoseBiasModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(body frames (T, 3, 3), linear features (T, L), all features (T, F)) of ``positions`` (T, J, 3) m."""
    return _all_features(positions, model.joint_names, model.frame_joints, model.groups, model.sensor_direction)


def feature_groups(joint_names: tuple[str, ...], groups, sensor_direction: bool = False) -> np.ndarray:
    """(F,) the index into ``groups`` of each column of the full features (:func:`pose_features`:
    a group's segment directions (and the direction towards the sensor), then their within-group products)."""
    sizes = [3 * len(seg) + 3 * bool(sensor_direction) for seg in _segment_index(tuple(joint_names), groups)]
    return np.concatenate([np.full(m + m * (m + 1) // 2, g) for g, m in enumerate(sizes)])


def _ridge_by_predictors(f: np.ndarray, e: np.ndarray, ridge: float, groups: np.ndarray,
                         predictors: tuple[tuple[int, ...] | None, ...] | None, k: int) -> np.ndarray:
    """Ridge weights (F, 3k) of the centred errors ``e`` (n, 3k) on the centred features ``f``
    (n, F), each corrected joint on the columns of its ``predictors`` groups only (0 elsewhere;
    None = every column), one solve per distinct set of groups."""
    predictors = (None,) * k if predictors is None else tuple(predictors)
    if len(predictors) != k:
        raise ValueError(f"predictors must name the groups of each of the {k} corrected joints, got {len(predictors)}")
    n, n_feat = f.shape
    gram, cross = f.T @ f, f.T @ e
    weights = np.zeros((n_feat, 3 * k))
    for key in set(predictors):
        cols = np.ones(n_feat, dtype=bool) if key is None else np.isin(groups, key)
        out = np.concatenate([[3 * i, 3 * i + 1, 3 * i + 2] for i, p in enumerate(predictors) if p == key])
        g = gram[np.ix_(cols, cols)] + ridge * n * np.eye(int(cols.sum()))
        weights[np.ix_(cols, out)] = np.linalg.solve(g, cross[np.ix_(cols, out)])
    return weights


def _nearest_centre_distance(linear: np.ndarray, centres: np.ndarray) -> np.ndarray:
    d2 = (linear * linear).sum(1)[:, None] - 2.0 * linear @ centres.T + (centres * centres).sum(1)[None, :]
    return np.sqrt(np.maximum(d2.min(axis=1), 0.0))


def familiarity(linear: np.ndarray, model: PoseBiasModel) -> np.ndarray:
    """(T,) share of the correction kept, 1 for poses like the training ones, 0 for poses unlike any
    (from the linear features ``linear`` (T, L) of :func:`pose_features`)."""
    dist = _nearest_centre_distance(linear, model.centres)
    return np.clip((model.fade_end - dist) / max(model.fade_end - model.fade_start, 1e-12), 0.0, 1.0)


def pose_bias(positions: np.ndarray, model: PoseBiasModel) -> np.ndarray:
    """The correction ``R^T e`` (T, J, 3) metres to subtract from ``positions`` (T, J, 3); 0 where not corrected."""
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1:] != (len(model.joint_names), 3):
        raise ValueError(f"positions must be (T, {len(model.joint_names)}, 3) for the {model.skeleton!r} bias model, "
                         f"got {pos.shape}")
    frames, linear, full = pose_features(pos, model)
    ok = np.isfinite(full).all(axis=1) & np.isfinite(frames).all(axis=(1, 2))
    out = np.zeros_like(pos)
    if not ok.any():
        return out
    k = len(model.corrected)
    e = ((full[ok] - model.feature_mean) @ model.weights).reshape(-1, k, 3)  # body frame
    fade = familiarity(linear[ok], model)
    norm = np.linalg.norm(e, axis=2)
    scale = fade[:, None] * np.minimum(1.0, model.max_correction_m[None, :] / np.maximum(norm, 1e-12))
    world = np.einsum("tij,tki->tkj", frames[ok], e * scale[..., None])  # R^T e
    out[ok] = np.einsum("jk,tkd->tjd", model.follow, world)
    return out


def remove_pose_bias(positions: np.ndarray, bones: np.ndarray, model: PoseBiasModel, alpha: float = 1.0,
                     previous_shift: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One body's consecutive frames ``positions`` (T, J, 3) m less the learned bias: (output, last shift (J, 3)).

    What the engine emits (``streamfix.streaming.finalise``). The correction moves joints
    one by one, so each corrected frame is put back on the bone lengths it had
    (position-based constraint iterations, a length target per frame, ``bones`` (B, 2)):
    unprojected, the correction varied UI-PRMD's bone lengths more than the raw sensor
    does. The resulting shift is smoothed along the frames by a one-pole low-pass of gain
    ``alpha`` (:func:`correction_gain`; 1 = none) continuing from ``previous_shift`` (the
    last shift returned for the frames before): the bias is slow, a noisy pose's estimate
    of it is not. Splitting the frames into consecutive runs gives the same output. A
    frame with a joint missing is not projected; a missing joint stays missing.
    """
    pos = np.asarray(positions, dtype=np.float64)
    out = pos - pose_bias(pos, model)
    whole = np.isfinite(pos).all(axis=(1, 2))
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if len(b) and whole.any():
        lengths = np.linalg.norm(pos[whole][:, b[:, 1]] - pos[whole][:, b[:, 0]], axis=2)  # each frame's own (n, B)
        out[whole] = project_pbd(out[whole], b, lengths, PROJECTION_ITERATIONS, None)
    # a missing joint has no shift (0, not NaN: the smoothing state must stay finite)
    shift = exponential_smoothing(np.nan_to_num(out - pos, nan=0.0), alpha, previous_shift)
    last = shift[-1] if len(shift) else (np.zeros(pos.shape[1:]) if previous_shift is None else previous_shift)
    return pos + shift, last


def body_frame_errors(output: np.ndarray, reference: np.ndarray, frames: np.ndarray, corrected_idx: np.ndarray) -> np.ndarray:
    """Error (T, K, 3) metres of ``output`` against ``reference`` at the corrected joints, in each frame's body frame."""
    return np.einsum("tij,tkj->tki", frames, output[:, corrected_idx] - reference[:, corrected_idx])


def _kmeans(x: np.ndarray, k: int, rng: np.random.Generator, iterations: int = 25) -> np.ndarray:
    """Lloyd's k-means (deterministic for a given generator); centres (k, D)."""
    centres = x[rng.choice(len(x), size=min(k, len(x)), replace=False)].copy()
    for _ in range(iterations):
        d2 = (x * x).sum(1)[:, None] - 2.0 * x @ centres.T + (centres * centres).sum(1)[None, :]
        label = d2.argmin(axis=1)
        counts = np.bincount(label, minlength=len(centres)).astype(np.float64)
        sums = np.zeros_like(centres)
        np.add.at(sums, label, x)
        filled = counts > 0
        centres[filled] = sums[filled] / counts[filled, None]
    return centres


def fit_pose_bias(
    takes: list[tuple[np.ndarray, np.ndarray]],
    *,
    skeleton: str,
    joint_names: tuple[str, ...],
    frame_joints: tuple[str, str, str, str],
    groups: tuple[tuple[tuple[str, str], ...], ...],
    corrected: tuple[str, ...],
    follow: dict[str, dict[str, float]] | None = None,
    ridge: float = 1e-2,
    n_centres: int = 64,
    seed: int = 0,
    min_frames: int = 20,
    training_subjects: tuple[str, ...] = (),
    predictors: tuple[tuple[int, ...] | None, ...] | None = None,
    sensor_direction: bool = False,
) -> PoseBiasModel:
    """Fit the model on ``takes``: (sensor output (T, J, 3), reference (T, J, 3)) pairs in metres.

    The output is what the correction will be applied to (the engine's clean output without
    it), the reference the optical joint centres on the same frames. Only frames where every
    needed joint and every corrected joint's reference is finite are used; a take with
    fewer than ``min_frames`` of them is skipped. ``ridge`` is relative to the number of
    frames (features are unit-scale). ``follow``: for joints not corrected, ``{joint:
    {corrected joint: weight}}``. ``predictors``: per corrected joint, the indices of the
    ``groups`` whose features predict its error (None, or a None entry: every group); the
    other groups' weights for that joint are 0. Why: in the training movements the arms and
    the legs move together in set ways (arms forward in a squat), so with every feature free
    a knee's predicted bias followed the arms, and a standing person's legs, which the
    sensor tracks well, moved with each arm raise (UI-PRMD's shoulder exercises).
    ``sensor_direction``: the direction towards the sensor joins every group (module doc).
    Deterministic for a given ``seed``.
    """
    names = tuple(joint_names)
    corrected_idx = np.array([names.index(n) for n in corrected])
    feats, errors, linears = [], [], []  # per take: all features, body-frame errors, linear features
    for output, reference in takes:
        output = np.asarray(output, dtype=np.float64)
        reference = np.asarray(reference, dtype=np.float64)
        frames, linear, full = _all_features(output, names, frame_joints, groups, sensor_direction)
        ok = (np.isfinite(full).all(axis=1) & np.isfinite(frames).all(axis=(1, 2))
              & np.isfinite(reference[:, corrected_idx]).all(axis=(1, 2))
              & np.isfinite(output[:, corrected_idx]).all(axis=(1, 2)))
        if ok.sum() < min_frames:
            continue
        feats.append(full[ok])
        errors.append(body_frame_errors(output[ok], reference[ok], frames[ok], corrected_idx).reshape(int(ok.sum()), -1))
        linears.append(linear[ok])
    if not feats:
        raise ValueError(f"no take has {min_frames} frames with every joint the {skeleton!r} bias model needs")
    f = np.concatenate(feats)
    mean = f.mean(axis=0)
    f -= mean
    e = np.concatenate(errors)
    e -= e.mean(axis=0)  # the average offset, a matter of definition, is not learned
    n, n_feat = f.shape
    weights = _ridge_by_predictors(f, e, ridge, feature_groups(names, groups, sensor_direction), predictors,
                                   len(corrected))
    lin_all = np.concatenate(linears)
    rng = np.random.default_rng(seed)
    sample = lin_all[rng.choice(len(lin_all), size=min(len(lin_all), 20000), replace=False)]
    centres = _kmeans(sample, n_centres, rng)
    dist = _nearest_centre_distance(lin_all, centres)
    pred = (f @ weights).reshape(n, len(corrected), 3)
    max_corr = np.quantile(np.linalg.norm(pred, axis=2), CLIP_QUANTILE, axis=0)
    mix = np.zeros((len(names), len(corrected)))
    mix[corrected_idx, np.arange(len(corrected))] = 1.0
    for joint, sources in (follow or {}).items():
        for source, w in sources.items():
            mix[names.index(joint), corrected.index(source)] = float(w)
    return PoseBiasModel(
        skeleton=skeleton, joint_names=names, frame_joints=tuple(frame_joints),
        groups=tuple(tuple(tuple(s) for s in g) for g in groups), corrected=tuple(corrected),
        feature_mean=mean, weights=weights, follow=mix, centres=centres,
        fade_start=float(np.quantile(dist, FADE_START_QUANTILE)), fade_end=float(FADE_END_FACTOR * dist.max()),
        max_correction_m=max_corr, ridge=float(ridge), training_subjects=tuple(training_subjects),
        sensor_direction=bool(sensor_direction),
    )
