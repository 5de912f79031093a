"""Stage 3 of the window cleaner: zero-lag smoothing whose span follows each joint's motion.

Used where the window's residuals say its samples carry white sensor noise
(:mod:`streamfix.core.pipeline`, stage 3 of its doc, decides how much).
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d

from .local_poly import fit_local_quadratic
from .points import point_norms

__all__ = ["motion_adaptive_smooth"]


def motion_adaptive_smooth(y: np.ndarray, w: np.ndarray, rate_hz: float, window_s: float, short_s: float | None,
                           bias_m: tuple[float, float]) -> tuple[np.ndarray, int]:
    """Zero-lag smoothing of ``y`` ``(T, 3J)`` whose span follows each joint's motion.

    Two weighted local quadratics (:func:`streamfix.core.local_poly.fit_local_quadratic`):
    long (span ``window_s`` s) and short (``short_s`` s; None = the long one only). Where
    they agree to within ``bias_m[0]`` m (per joint, averaged over a short span) the long
    one is used: its bias is that small and it averages more noise; above ``bias_m[1]``
    the short one; in between a smooth
    blend (Lepski's rule with two bandwidths and an absolute tolerance). Why: slow
    rehabilitation movement wants 0.7 s (UI-PRMD against Vicon), a walking leg wants
    0.2 s: one fixed 0.7 s span made stylised walking with the sensor protocol's noise
    *worse* than the unsmoothed input. The price: correlated sensor noise makes the
    two fits part as much as motion does, so on slow movement the short fit wins more
    often than it should and the output keeps more jitter than a fixed long span would
    (``short_s=None`` gives that span to every joint, for slow-motion work such as
    rehabilitation). Returns the smoothed array and the long half-width (frames).
    """
    T = y.shape[0]
    hl = max(2, int(round(window_s * rate_hz / 2)))
    short_s = window_s if short_s is None else short_s
    hs = min(hl, max(1, int(round(short_s * rate_hz / 2))))
    long_, _ = fit_local_quadratic(y, w, hl)
    if hs == hl:
        return long_, hl
    short, _ = fit_local_quadratic(y, w, hs)
    dev = point_norms((long_ - short).reshape(T, -1, 3))  # (T, J) m
    lo, hi = bias_m
    dev = correlate1d(dev, np.full(2 * hs + 1, 1.0 / (2 * hs + 1)), axis=0, mode="nearest")
    z = np.clip((hi - dev) / max(hi - lo, 1e-12), 0.0, 1.0)
    a = np.repeat(z * z * (3.0 - 2.0 * z), 3, axis=1)  # weight of the long fit
    return a * long_ + (1.0 - a) * short, hl
