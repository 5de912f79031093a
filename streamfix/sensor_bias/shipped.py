"""The shipped pose-bias models and the engine setting that picks one.

``EngineConfig.sensor_bias`` (and ``--sensor-bias`` of ``clean`` / ``serve``) is ``"auto"``
(the shipped model of the stream's skeleton, if there is one), ``None`` / ``"off"`` (no
correction), a path to a model file (``streamfix train-bias`` writes them) or a
:class:`~streamfix.core.pose_bias.PoseBiasModel`.
"""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from ..core.pose_bias import PoseBiasModel
from ..io.pose_bias_model import load_pose_bias
from ..skeletons import Skeleton

__all__ = ["MODELS_DIR", "shipped_model", "preload_shipped_models", "resolve_sensor_bias", "is_model_path", "OFF"]

MODELS_DIR = Path(__file__).resolve().parent / "models"
OFF = ("off", "none", "")


def is_model_path(setting: Any) -> bool:
    """True when ``setting`` names a model file rather than ``auto`` / ``off`` (or is a model)."""
    return isinstance(setting, (str, Path)) and str(setting).lower() not in OFF + ("auto",)


@functools.lru_cache(maxsize=None)
def shipped_model(skeleton_name: str) -> PoseBiasModel | None:
    """The model shipped for ``skeleton_name`` (``models/<name>.npz``), None if there is none."""
    path = MODELS_DIR / f"{skeleton_name}.npz"
    return load_pose_bias(path) if path.is_file() else None


def preload_shipped_models() -> None:
    """Read every shipped model into :func:`shipped_model`'s cache now: ``serve`` calls this
    before it listens, so the first stream of a layout with a model does not read and parse
    its file on the input loop."""
    for path in sorted(MODELS_DIR.glob("*.npz")):
        shipped_model(path.stem)


def resolve_sensor_bias(setting: Any, skeleton: Skeleton) -> PoseBiasModel | None:
    """The model ``setting`` names for a stream of ``skeleton`` (see the module doc), None for none.

    A model for another layout is an error naming both layouts' joints counts and names.
    """
    if setting is None or (isinstance(setting, str) and setting.lower() in OFF):
        return None
    if isinstance(setting, str) and setting.lower() == "auto":
        model = shipped_model(skeleton.name)
        return model if model is not None and model.joint_names == tuple(skeleton.joint_names) else None
    model = setting if isinstance(setting, PoseBiasModel) else load_pose_bias(Path(setting))
    if model.joint_names != tuple(skeleton.joint_names):
        raise ValueError(
            f"sensor-bias model for {model.skeleton!r} ({len(model.joint_names)} joints) does not fit skeleton "
            f"{skeleton.name!r} ({skeleton.n_joints} joints: {', '.join(skeleton.joint_names)})")
    return model
