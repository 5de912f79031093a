"""Real Kinect v2 recordings (no ground truth): smoothness, bone stability, inferred joints.

For each file and method, a record::

    {file, rate_hz, protocol: "kinect", level: 0, method, aje_m: None, abe_m: None,
     jitter, jitter_input, jitter_ratio,            # m/frame^2, on observed joint-frames
     bone_cv, bone_cv_input, bone_cv_ratio,          # mean over bones of std/mean length
     inferred_fraction,                              # joint-frames the SDK inferred
     inferred_shift_m,                               # mean |output - input| on inferred joint-frames
     tracked_shift_m,                                # same on tracked joint-frames
     inferred_bone_cv, inferred_bone_cv_input,       # bone CV over frames with an inferred joint
     inferred_asymmetry, inferred_asymmetry_input,   # worst inferred-limb bone vs its mirror (fraction)
     rigid_shift_bound_m, tenth_shift_bound_m,       # per file: the least mean move of tracked joint-frames
                                                     #   that makes every bone its median length / cuts
                                                     #   every bone's length error to a tenth (core.rigid_bound)
     least_move_m, least_move_feasible,              # with least_move=True, per file: the least mean move of
                                                     #   tracked joint-frames found for an output with jitter at
                                                     #   most median_savgol's and bone CV at most a tenth of the
                                                     #   input's (core.least_move; None without it)
     time_s}

``*_ratio`` = after / before (lower is better). The ``level`` argument is ignored.
"""
from __future__ import annotations

import time

import numpy as np

from ..core import metrics
from ..core.least_move import least_move_meeting_bars
from ..core.rigid_bound import least_shift_to_rigid
from ..limbs import mirror_bones
from .registry import METHODS, load_motion, run_method

__all__ = ["run_kinect", "PROTOCOLS", "TRACKED_MOVE_BAR", "LEAST_MOVE_CV_SHARE"]


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


TRACKED_MOVE_BAR = 1.5
"""Issue 8's bar on real Kinect files: the tracked joints moved on average at most this x what
median_savgol moves them (``tracked_shift_m``)."""

LEAST_MOVE_CV_SHARE = 0.1
"""The bone-CV bar :func:`least_move_meeting_bars` is asked to meet: this x the input's (issue 8)."""


def run_kinect(paths, *, rate_hz=None, levels=None, seed=0, methods=None, least_move: bool = False) -> list[dict]:
    """Score each method on real recordings (see the module doc for the record).

    ``least_move``: also find, per file, the least move of the tracked joints with which an
    output meets median_savgol's jitter and a bone CV :data:`LEAST_MOVE_CV_SHARE` of the
    input's (:mod:`streamfix.core.least_move`, seconds per file); needs ``median_savgol``
    among the methods."""
    if least_move and "median_savgol" not in (methods or METHODS):
        raise ValueError("least_move needs median_savgol among the methods (its jitter is the bar)")
    methods = list(methods or METHODS)  # the methods these protocols run (not other protocols')
    records: list[dict] = []
    for path in paths:
        motion = load_motion(path, rate_hz)
        x = np.asarray(motion.positions, dtype=np.float64)
        conf = motion.confidence
        obs = motion.observed
        inferred = obs & (conf < 1.0)
        tracked = obs & (conf >= 1.0)
        bones = motion.skeleton.bone_array
        any_inf = inferred.any(axis=1)
        jit_in = metrics.jitter(x)
        cv_in = metrics.bone_length_cv(x, bones)
        cv_inf_in = metrics.bone_length_cv(x, bones, any_inf) if any_inf.sum() >= 2 else None
        mirror = mirror_bones(motion.skeleton)
        asym_in = metrics.inferred_bone_asymmetry(x, inferred, bones, mirror)
        n_tracked = max(int(tracked.sum()), 1)
        rigid_bound = float(least_shift_to_rigid(x, obs, tracked, bones).sum()) / n_tracked
        tenth_bound = float(least_shift_to_rigid(x, obs, tracked, bones, keep=0.1).sum()) / n_tracked
        first = len(records)
        for name in methods:
            t0 = time.perf_counter()
            y = run_method(name, x, conf, bones, motion.rate_hz, skeleton=motion.skeleton)
            dt = time.perf_counter() - t0
            y_obs = np.where(obs[..., None], y, np.nan)  # judge on what the sensor saw
            jit = metrics.jitter(y_obs)
            cv = metrics.bone_length_cv(y_obs, bones)
            records.append({
                "file": str(path),
                "rate_hz": motion.rate_hz,
                "protocol": "kinect",
                "level": 0.0,
                "method": name,
                "n_frames": int(x.shape[0]),
                "n_joints": int(x.shape[1]),
                "aje_m": None,
                "abe_m": None,
                "gap_mae_m": None,
                "jitter": jit,
                "jitter_input": jit_in,
                "jitter_ratio": jit / jit_in if jit_in > 0 else None,
                "bone_cv": cv,
                "bone_cv_input": cv_in,
                "bone_cv_ratio": cv / cv_in if cv_in > 0 else None,
                "inferred_fraction": float(inferred.sum() / max(obs.sum(), 1)),
                "inferred_shift_m": _finite(metrics.mean_move(y, x, inferred)),
                "tracked_shift_m": _finite(metrics.mean_move(y, x, tracked)),
                "inferred_bone_cv": metrics.bone_length_cv(y_obs, bones, any_inf) if any_inf.sum() >= 2 else None,
                "inferred_bone_cv_input": cv_inf_in,
                "inferred_asymmetry": _finite(metrics.inferred_bone_asymmetry(y, inferred, bones, mirror)),
                "inferred_asymmetry_input": _finite(asym_in),
                "rigid_shift_bound_m": rigid_bound,
                "tenth_shift_bound_m": tenth_bound,
                "least_move_m": None,
                "least_move_feasible": None,
                "time_s": dt,
            })
            if name == "median_savgol":
                smoother, smoother_jitter = y, jit
        if least_move:
            found = least_move_meeting_bars(x, tracked, obs, bones, smoother_jitter, LEAST_MOVE_CV_SHARE * cv_in,
                                            start=smoother)
            for r in records[first:]:
                r["least_move_m"], r["least_move_feasible"] = found.move_m, found.feasible
    return records


PROTOCOLS = {"kinect": run_kinect}
