"""How far a tracked bone may stray from its length before the projection corrects it.

Why: a sensor's "bones" are not rigid. A Kinect's joints are its own estimates of joint
centres, and the distance between two of them changes with the pose by a few per cent
(on the KERAAL recording the tracked shin's length has a 1.1 cm standard deviation and a
6.7 cm range while the ankle is within 3 mm of the Vicon); a spine "bone" spans
several vertebrae and bends. Pulling every sample to one length then moves joints the
sensor has right, and since a length error does not say which end is wrong, the move
goes to the right end as often as to the wrong one: against Vicon the exact projection
made the KERAAL elbows and ankles worse than the raw input, and on exact mocap it was
most of the cleaner's damage to uncorrupted frames (``benchmarks/bench_sensor.py``,
``benchmarks/bench_paired.py``).

So a tracked bone keeps its own length as the projection's target while that is within
a band around the body's length for it, and gets the band's nearer edge beyond (a target,
not a free band: a kept bone still holds the length it has while the corrections of the
bones beside it move its ends, instead of passing them along unopposed). The kept play is
smoothed over a fraction of a second: it follows the pose, which changes slowly, while
frame-to-frame length changes are noise the projection still removes (kept raw, they
raised the UI-PRMD output's jitter). The band is a fraction of the
length (the pose-dependent play of real skeletons), narrowed by the noise the bone's two
ends carry: where the joints are noisy (every-sample jitter of centimetres), a length
deviation inside the band is mostly that noise, and the exact projection removes a part
of it; where they are precise, a deviation is real. Bones with an end that is missing,
an outlier, a fill or below ``min_confidence`` (a Kinect *inferred* joint) get no band:
a guess has no length of its own to keep.

Arrays: confidence and masks ``(T, J)``, bones ``(B, 2)`` joint indices, lengths ``(B,)``
and noise scales ``(J,)`` in metres; the band is ``(T, B)`` metres.
"""
from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from .isometry import bone_lengths_per_frame

__all__ = ["length_tolerance", "length_targets", "LENGTH_TOLERANCE", "NOISE_MULTIPLE", "TRUSTED_CONFIDENCE",
           "PLAY_SMOOTH_S"]

LENGTH_TOLERANCE = 0.04
"""The band's half-width as a fraction of the bone's length, for noise-free ends."""

NOISE_MULTIPLE = 6.0
"""The band narrows by this many times the bone's noise scale ``sqrt(s_i^2 + s_j^2)`` (m)."""

TRUSTED_CONFIDENCE = 0.75
"""Both ends at or above this confidence (tracked 1.0, inferred 0.5) for a band."""

PLAY_SMOOTH_S = 0.3
"""Span (s) of the two box filters that smooth the kept play (a triangle twice as long)."""


def length_tolerance(
    bones: np.ndarray,
    lengths: np.ndarray,
    noise_m: np.ndarray,
    confidence: np.ndarray,
    trusted: np.ndarray,
    fraction: float = LENGTH_TOLERANCE,
    noise_multiple: float = NOISE_MULTIPLE,
    min_confidence: float = TRUSTED_CONFIDENCE,
) -> np.ndarray:
    """``(T, B)`` metres: per frame and bone, how far the bone's length may stray from
    ``lengths`` and still be kept by the projection (0 = exact projection).

    ``max(0, fraction * length - noise_multiple * sqrt(s_i^2 + s_j^2))`` where both ends
    are ``trusted`` (observed, not an outlier) with ``confidence >= min_confidence``;
    0 elsewhere and for bones without a finite length. ``noise_m`` ``(J,)``: each
    joint's noise scale (m, :func:`streamfix.core.bone_projection.joint_noise_scale`).
    """
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    lengths = np.asarray(lengths, dtype=np.float64)
    s = np.asarray(noise_m, dtype=np.float64)
    ok = np.asarray(trusted, dtype=bool) & (np.asarray(confidence, dtype=np.float64) >= min_confidence)
    noise = np.sqrt(s[b[:, 0]] ** 2 + s[b[:, 1]] ** 2)
    band = np.maximum(0.0, fraction * np.nan_to_num(lengths, nan=0.0) - noise_multiple * noise)
    return np.where(ok[:, b[:, 0]] & ok[:, b[:, 1]], band[None, :], 0.0)


def length_targets(
    positions: np.ndarray, bones: np.ndarray, lengths: np.ndarray, band: np.ndarray, smooth_frames: int = 0
) -> np.ndarray:
    """``(T, B)`` metres: each bone's target length per frame for the projection.

    ``lengths`` plus the bone's own deviation from it in ``positions`` ``(T, J, 3)``,
    clipped to ``+-band`` ``(T, B)``, then smoothed over time by two centred box filters of
    ``smooth_frames`` (0 or 1: none) and clipped again (so the target never leaves the
    band, and a bone beyond it on a few frames pulls its neighbours' targets by at most the
    band). A bone without a length stays NaN; a frame where the bone is not finite keeps
    ``lengths``.
    """
    base = np.asarray(lengths, dtype=np.float64)[None, :]
    band = np.asarray(band, dtype=np.float64)
    own = bone_lengths_per_frame(positions, bones)
    dev = np.clip(np.nan_to_num(own - base, nan=0.0), -band, band)
    if smooth_frames > 1 and dev.shape[0] > 1:
        dev = uniform_filter1d(uniform_filter1d(dev, smooth_frames, axis=0, mode="nearest"), smooth_frames, axis=0,
                               mode="nearest")
        dev = np.clip(dev, -band, band)
    return base + dev
