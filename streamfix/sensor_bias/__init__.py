"""Learned pose-dependent sensor bias (:mod:`streamfix.core.pose_bias`): the layouts it is
defined for, the shipped models and how to choose one, and training from paired recordings."""
from .layouts import BIAS_LAYOUTS, BiasLayout
from .shipped import MODELS_DIR, resolve_sensor_bias, shipped_model

__all__ = ["BIAS_LAYOUTS", "BiasLayout", "MODELS_DIR", "resolve_sensor_bias", "shipped_model"]
