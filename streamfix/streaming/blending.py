"""Overlap-add of consecutive windows: the weight each window gets on the frames it shares
with its neighbours (a crossfade at every hand-over; see :mod:`streamfix.streaming.engine`)."""
from __future__ import annotations

import numpy as np

__all__ = ["HANDOVER_S", "crossfade_frames", "handover_frames", "handover_weights"]

HANDOVER_S = 0.17  # crossfade at a window hand-over (5 frames at 30 Hz); see handover_weights


def handover_weights(future: np.ndarray, lookahead: int, hop: int, crossfade: int | None = None) -> np.ndarray:
    """Overlap-add weight of a window for frames that saw ``future`` (>= 1) of its frames
    after them: a complementary crossfade over the ``K = L + 1 - H`` frames two
    consecutive windows share.

    A frame ``n`` is blended from the windows ending at ``e`` with ``1 <= d = e - n <= L + 1``;
    with a regular hop, two consecutive windows overlap on ``K`` frames where the older
    one has ``d = K - j`` and the newer ``d = L + 1 - j`` (``j = 0..K-1``). The weight
    rises as ``s((d - 1/2) / K)`` over the first ``K`` values of ``d`` and falls as
    ``s((L + 3/2 - d) / K)`` over the last ``K``, ``s`` the smoothstep: on the shared frames
    the two weights sum to 1 (``s(x) + s(1 - x) = 1``), the newer window (more future,
    fewer edge effects) takes over smoothly, and neither window's arrival nor departure
    steps the output. ``crossfade`` ``F <= K`` shortens the fade to the first ``F`` shared
    frames: the newer window then takes over sooner. The engine uses ``HANDOVER_S``: a
    longer fade hides hand-overs better but leaves more frames to the older window's edge,
    which costs accuracy under heavy corruption; 0.17 s is the longest fade that keeps the
    clean output within 1.25x of the whole-take solve at 20 % (``tests/test_e2e_quality.py``),
    the seam is checked by ``tests/test_support_limbs.py`` and the benchmarks' seam ratio.
    A taper by position in the window gave the entering window about half the weight: a
    kink in the clean output every hop.
    """
    d = np.asarray(future, dtype=np.float64)
    K = max(int(lookahead) + 1 - int(hop), 1)
    F = K if crossfade is None else min(max(int(crossfade), 1), K)

    def smoothstep(z: np.ndarray) -> np.ndarray:
        z = np.clip(z, 0.0, 1.0)
        return z * z * (3.0 - 2.0 * z)

    rise = smoothstep((d - 0.5 - (K - F)) / F)
    fall = smoothstep((lookahead + 1.5 - d) / F)
    return 1e-3 + np.minimum(rise, fall)


def crossfade_frames(handover_s: float, rate_hz: float) -> int:
    """The crossfade ``handover_s`` (s) in frames at ``rate_hz`` (Hz), at least 1."""
    return max(1, int(round(float(handover_s) * float(rate_hz))))


def handover_frames(n_frames: int, lookahead: int, hop: int, crossfade: int) -> np.ndarray:
    """``(T,)`` bool: the two frames around each window hand-over of the engine's blend.

    Windows end at ``e_k = L + 1 + k H`` (the engine's schedule for a body's timeline) and
    frame ``n`` is blended from those with ``1 <= e - n <= L + 1`` by
    :func:`handover_weights`; the hand-over is the first frame whose largest weight belongs
    to a newer window than its predecessor's. That frame and the one before it are marked:
    where a crossfade that does not hide the change between two windows' solutions shows
    as a kink.
    """
    T = int(n_frames)
    out = np.zeros(max(T, 0), dtype=bool)
    L, H = int(lookahead), int(hop)
    if T < 2:
        return out
    ends = np.arange(L + 1, T + L + 2, H)  # every window that blends into a frame < T
    d = ends[None, :] - np.arange(T)[:, None]  # (T, K)
    valid = (d >= 1) & (d <= L + 1)
    w = np.where(valid, handover_weights(np.clip(d, 1, L + 1), L, H, crossfade), -np.inf)
    has = valid.any(axis=1)
    dominant = np.where(has, np.argmax(w, axis=1), -1)
    switch = np.flatnonzero((dominant[1:] > dominant[:-1]) & has[1:] & has[:-1]) + 1
    out[switch] = True
    out[switch - 1] = True
    return out

