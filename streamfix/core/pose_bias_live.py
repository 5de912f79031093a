"""The learned sensor bias removed one frame at a time, for the causal ``live`` topic (pure math).

Why: :func:`streamfix.core.pose_bias.remove_pose_bias` corrects a run of frames with numpy
calls sized for the ``clean`` topic's batches; on a single frame their overhead is most of a
millisecond, more than the whole live path of a body. :class:`LivePoseBias` prepares the
model's index arrays once and corrects a frame in one compiled call (the features, the ridge
map, the familiarity fade, the clip, the rotation back to the world) plus the compiled
bone-length projection, with the numpy batch function as the reference it is tested
against (same values up to summation order; the numpy path is what runs without numba).
"""
from __future__ import annotations

import numpy as np

from . import kernels
from .pose_bias import (
    MIN_SENSOR_DISTANCE_M,
    PROJECTION_ITERATIONS,
    SENSOR_FAMILIARITY_WEIGHT,
    PoseBiasModel,
    remove_pose_bias,
)

__all__ = ["LivePoseBias"]


class LivePoseBias:
    """``step(position (J, 3), previous_shift) -> (corrected (J, 3), shift (J, 3))``: what
    ``remove_pose_bias(position[None], bones, model, alpha, previous_shift)`` gives for one frame."""

    def __init__(self, model: PoseBiasModel, bones: np.ndarray, alpha: float) -> None:
        self.model = model
        self.bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
        self.alpha = float(alpha)
        names = tuple(model.joint_names)
        segments = [[(names.index(a), names.index(b)) for a, b in group] for group in model.groups]
        seg = np.array([s for group in segments for s in group], dtype=np.intp).reshape(-1, 2)
        starts = np.cumsum([0] + [len(g) for g in segments]).astype(np.intp)
        self._prepared = (
            np.array([names.index(n) for n in model.frame_joints], dtype=np.intp),
            np.ascontiguousarray(seg[:, 0]), np.ascontiguousarray(seg[:, 1]), starts,
            bool(model.sensor_direction), float(SENSOR_FAMILIARITY_WEIGHT), float(MIN_SENSOR_DISTANCE_M),
            np.ascontiguousarray(model.feature_mean, dtype=np.float64),
            np.ascontiguousarray(model.weights, dtype=np.float64),
            np.ascontiguousarray(model.centres, dtype=np.float64),
            float(model.fade_start), float(model.fade_end),
            np.ascontiguousarray(model.max_correction_m, dtype=np.float64),
            np.ascontiguousarray(model.follow, dtype=np.float64),
        )
        # the bone projection's constraints for one frame (equal inverse masses), as
        # kernels.project_bone_lengths_pbd builds them; the target lengths are each frame's own
        bi, bj, _, share_i, degree = kernels.pbd_constraints((1, len(names), 3), self.bones, np.ones(len(self.bones)), None)
        inv_degree = 1.0 / np.maximum(degree, 1.0)
        self._prepared += (
            bi, bj, np.ascontiguousarray((share_i * inv_degree[bi]).T), np.ascontiguousarray(((1.0 - share_i) * inv_degree[bj]).T),
            int(PROJECTION_ITERATIONS), self.alpha,
        )

    def step(self, position: np.ndarray, previous_shift: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """One frame ``(J, 3)`` m less the bias, on its own bone lengths, the shift smoothed
        with gain ``alpha`` from ``previous_shift`` (None: unsmoothed). Missing joints stay missing."""
        pos = np.asarray(position, dtype=np.float64)
        if pos.shape != (len(self.model.joint_names), 3):  # the compiled call would read past it
            raise ValueError(f"a frame must be ({len(self.model.joint_names)}, 3) for the {self.model.skeleton!r} "
                             f"bias model, got {pos.shape}")
        if not kernels.COMPILED:
            out, last = remove_pose_bias(pos[None], self.bones, self.model, self.alpha, previous_shift)
            return out[0], last
        return kernels.live_pose_bias(pos, self._prepared, previous_shift)
