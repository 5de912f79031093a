"""Overlap-add of consecutive windows: the weight each window gets on the frames it shares
with its neighbours (a crossfade at every hand-over; see :mod:`streamfix.streaming.engine`)."""
from __future__ import annotations

import numpy as np

__all__ = ["HANDOVER_S", "handover_weights"]

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
