"""The numbers a cleaning report states: input condition, smoothness, bone stability, error vs a reference.

Pure numpy over ``(T, J, 3)`` metres (NaN = missing). Errors against an optical reference
are given raw and *debiased*: marker-based references sit a few centimetres off the
joint centres a sensor estimates, so each joint's mean offset over the take is removed
before scoring (``../shared/data/paired/README.md``).
"""
from __future__ import annotations

import warnings

import numpy as np

from ..core.metrics import bone_length_cv, jitter
from ..motion import Motion

__all__ = ["joint_reference_errors", "summarise"]


def _nanmean(a: np.ndarray, axis=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(a, axis=axis)


def joint_reference_errors(positions: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint mean error (m) against ``reference``: ``(raw (J,), debiased (J,))``, NaN without reference."""
    x = np.asarray(positions, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if x.shape != ref.shape:
        raise ValueError(f"positions {x.shape} and reference {ref.shape} must have the same (T, J, 3) shape")
    d = ref - x
    raw = _nanmean(np.linalg.norm(d, axis=2), axis=0)
    debiased = _nanmean(np.linalg.norm(d - _nanmean(d, axis=0), axis=2), axis=0)
    return raw, debiased


def summarise(raw: Motion, clean: Motion, reference: np.ndarray | None = None) -> dict:
    """Summary numbers of one cleaning: fractions, jitter (mm/frame^2), bone CV (%), errors (cm)."""
    bones = raw.skeleton.bone_array
    observed = np.isfinite(raw.positions).all(axis=2) & (raw.confidence > 0)
    inferred = observed & (raw.confidence < 1)
    recovered = clean.recovered if clean.recovered is not None else ~observed & np.isfinite(clean.positions).all(axis=2)
    out = {
        "frames": raw.n_frames,
        "rate_hz": raw.rate_hz,
        "duration_s": raw.n_frames / raw.rate_hz,
        "joints": raw.n_joints,
        "missing_pct": 100.0 * float((~observed).mean()),
        "inferred_pct": 100.0 * float(inferred.mean()),
        "recovered_pct": 100.0 * float(np.asarray(recovered).mean()),
        "jitter_raw_mm": 1e3 * jitter(raw.positions),
        "jitter_clean_mm": 1e3 * jitter(clean.positions),
        "bone_cv_raw_pct": 100.0 * bone_length_cv(raw.positions, bones),
        "bone_cv_clean_pct": 100.0 * bone_length_cv(clean.positions, bones),
    }
    if reference is not None:
        for name, x in (("raw", raw.positions), ("clean", clean.positions)):
            err, deb = joint_reference_errors(x, reference)
            out[f"ref_error_{name}_cm"] = 100.0 * float(_nanmean(err))
            out[f"ref_error_debiased_{name}_cm"] = 100.0 * float(_nanmean(deb))
    return out
