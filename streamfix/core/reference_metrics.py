"""Scoring a sensor's skeleton against a reference measured by another system.

A reference from optical motion capture (markers on the skin) and a sensor's joint
centres differ by a roughly constant offset per joint that no cleaner can or should
remove, and the two clocks are aligned only approximately. These measures separate
what a cleaner changes from what the measurement set-up fixes:

* :func:`remove_mean_offset` -- subtract each joint's mean offset to the reference
  over the take ("debiased"); the remaining error is jitter, drift and tracking
  failures;
* :func:`second_difference_norm` -- ``|x_{t+1} - 2 x_t + x_{t-1}|`` per joint-frame
  (m/frame^2), the per-sample form of :func:`streamfix.core.metrics.jitter`, so that
  it can be pooled over takes or split by frame (e.g. window hand-overs);
* :func:`velocity_xcorr` -- normalised cross-correlation of velocities against the
  reference's over a range of lags (frames); its argmax is the output's delay;
* :func:`slow_error_norm` -- the debiased error's part below a cut-off (zero-phase
  low-pass): a linear zero-lag filter that passes movement below the cut-off passes this
  error too (the robust smoothers measured beside it leave it nearly unchanged);
  only a cleaner that knows where the joint should be removes it (a failed limb
  replaced, a sensor's pose-dependent bias learned).

Arrays in, arrays out: positions ``(T, J, 3)`` metres, NaN = no sample.
"""
from __future__ import annotations

import warnings

import numpy as np

from .filters import butterworth
from .metrics import _check_pair as _pair  # (T, J, 3) pairs, one validation for all metrics

__all__ = ["remove_mean_offset", "second_difference_norm", "slow_error_norm", "velocity_xcorr", "SLOW_CUTOFF_HZ"]

SLOW_CUTOFF_HZ = 3.0
"""Cut-off (Hz) of :func:`slow_error_norm`: below it lies human movement itself (a 6 Hz
low-pass is the markerless pipelines' default; 3 Hz keeps every smoother's pass band)."""


def remove_mean_offset(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``pred`` minus each joint's mean ``pred - ref`` over the frames where both exist.

    A joint with no common frame is returned unchanged (its error stays NaN anyway).
    """
    pred, ref = _pair(pred, ref)
    d = pred - ref
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # joints without a reference
        offset = np.nanmean(np.where(np.isfinite(d).all(axis=2, keepdims=True), d, np.nan), axis=0)
    return pred - np.nan_to_num(offset)


def second_difference_norm(positions: np.ndarray) -> np.ndarray:
    """``(T, J)`` ``|x_{t+1} - 2 x_t + x_{t-1}|`` (m/frame^2); NaN on the first and last frame."""
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3), got {x.shape}")
    out = np.full(x.shape[:2], np.nan)
    if x.shape[0] >= 3:
        out[1:-1] = np.linalg.norm(x[2:] - 2.0 * x[1:-1] + x[:-2], axis=2)
    return out


def slow_error_norm(pred: np.ndarray, ref: np.ndarray, rate_hz: float, cutoff_hz: float = SLOW_CUTOFF_HZ) -> np.ndarray:
    """``(T, J)`` m: ``|lowpass(debiased pred - ref)|`` per joint-frame, NaN where either is missing.

    The debiased error (:func:`remove_mean_offset`) is low-passed along time (zero-phase
    2nd-order Butterworth at ``cutoff_hz``, gaps bridged linearly for the filter only). On
    the raw input this is the error a smoother that keeps movement below the cut-off cannot
    touch: it brings the output's error down to about this, not below.
    """
    pred, ref = _pair(pred, ref)
    err = remove_mean_offset(pred, ref) - ref
    both = np.isfinite(err).all(axis=2)
    slow = butterworth(err, rate_hz, both, cutoff_hz=cutoff_hz)
    return np.where(both, np.linalg.norm(slow, axis=2), np.nan)


def velocity_xcorr(pred: np.ndarray, ref: np.ndarray, max_lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Lags ``-max_lag..max_lag`` (frames) and the normalised velocity cross-correlation.

    ``c(l) = sum_t v_pred(t + l) . v_ref(t) / sqrt(sum |v_pred|^2 sum |v_ref|^2)`` over the
    joints given and the frames where both velocities exist. A positive argmax ``l``
    means the output follows the reference ``l`` frames late.
    """
    pred, ref = _pair(pred, ref)
    if max_lag < 0:
        raise ValueError(f"max_lag must be >= 0 frames, got {max_lag}")
    vp, vr = np.diff(pred, axis=0), np.diff(ref, axis=0)
    okp, okr = np.isfinite(vp).all(axis=2), np.isfinite(vr).all(axis=2)
    vp, vr = np.where(okp[..., None], vp, 0.0), np.where(okr[..., None], vr, 0.0)
    lags = np.arange(-max_lag, max_lag + 1)
    corr = np.full(len(lags), np.nan)
    n = vp.shape[0]
    for i, lag in enumerate(lags):  # 2 max_lag + 1 shifts, each vectorised over frames and joints
        a, b = max(0, -lag), min(n, n - lag)  # reference frames t with t + lag inside
        if b - a < 2:
            continue
        p, r = vp[a + lag:b + lag], vr[a:b]
        m = (okp[a + lag:b + lag] & okr[a:b])[..., None]
        den = np.sqrt(np.sum(p * p * m) * np.sum(r * r * m))
        if den > 0:
            corr[i] = np.sum(p * r * m) / den
    return lags, corr
