"""Pose-bias model files (:class:`streamfix.core.pose_bias.PoseBiasModel`): one ``.npz``, no pickles.

The arrays are stored as arrays; names, segment groups and scalars as one JSON string
(``meta``), so a file can be read without running code from it (``allow_pickle=False``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core.pose_bias import PoseBiasModel

__all__ = ["save_pose_bias", "load_pose_bias", "FORMAT"]

FORMAT = "streamfix-pose-bias-2"
# version 1 had no ``sensor_direction`` (always off); version 2 records it. An older reader refuses a
# version-2 file by name instead of applying weights to features it does not compute.
_READABLE = ("streamfix-pose-bias-1", FORMAT)
_ARRAYS = ("feature_mean", "weights", "follow", "centres", "max_correction_m")


def save_pose_bias(model: PoseBiasModel, path: str | Path) -> Path:
    """Write ``model`` to ``path`` (``.npz``); returns the path."""
    meta = {
        "format": FORMAT, "skeleton": model.skeleton, "joint_names": list(model.joint_names),
        "frame_joints": list(model.frame_joints), "groups": [[list(s) for s in g] for g in model.groups],
        "corrected": list(model.corrected), "fade_start": model.fade_start, "fade_end": model.fade_end,
        "ridge": model.ridge, "training_subjects": list(model.training_subjects),
        "sensor_direction": bool(model.sensor_direction),
    }
    path = Path(path)
    with open(path, "wb") as fh:  # a file object: np.savez would append .npz to a name without it
        np.savez(fh, meta=np.array(json.dumps(meta, sort_keys=True)),
                 **{k: np.asarray(getattr(model, k), dtype=np.float64) for k in _ARRAYS})
    return path


def load_pose_bias(path: str | Path) -> PoseBiasModel:
    """Read a model written by :func:`save_pose_bias`; ``ValueError`` naming the file if it is not one."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: np.array(z[k]) for k in _ARRAYS}
    except (KeyError, json.JSONDecodeError, OSError, ValueError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise ValueError(f"{path}: not a streamfix pose-bias model ({exc})") from None
    if meta.get("format") not in _READABLE:
        raise ValueError(f"{path}: format {meta.get('format')!r}, expected one of {', '.join(map(repr, _READABLE))}")
    k, j = len(meta["corrected"]), len(meta["joint_names"])
    if arrays["weights"].shape[1] != 3 * k or arrays["follow"].shape != (j, k):
        raise ValueError(f"{path}: weights {arrays['weights'].shape} / follow {arrays['follow'].shape} do not fit "
                         f"{k} corrected joints of {j}")
    return PoseBiasModel(
        skeleton=meta["skeleton"], joint_names=tuple(meta["joint_names"]), frame_joints=tuple(meta["frame_joints"]),
        groups=tuple(tuple(tuple(s) for s in g) for g in meta["groups"]), corrected=tuple(meta["corrected"]),
        fade_start=float(meta["fade_start"]), fade_end=float(meta["fade_end"]), ridge=float(meta["ridge"]),
        training_subjects=tuple(meta.get("training_subjects", ())),
        sensor_direction=bool(meta.get("sensor_direction", False)), **arrays,
    )
