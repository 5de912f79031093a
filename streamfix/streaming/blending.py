"""Overlap-add of consecutive windows: the weight each window gets on the frames it shares
with its neighbours (a crossfade at every hand-over; see :mod:`streamfix.streaming.engine`)."""
from __future__ import annotations

import numpy as np

__all__ = ["FILL_DISTANCE_M", "FILL_SMOOTH_S", "HANDOVER_S", "OUTPUT_SMOOTH_S", "crossfade_frames", "handover_frames", "handover_weights",
           "next_window_end", "smooth_blended", "window_ends"]

HANDOVER_S = 0.17  # crossfade at a window hand-over (5 frames at 30 Hz); see handover_weights
# binomial half-width of the output smoothing: 2 frames at 30 Hz = the 9-tap twiced kernel. Wider
# than 1 frame since clean_window keeps the median estimator only where it is unbiased
# (core/pipeline.py, stage 1): the windows where a noisy sensor lost it (UI-PRMD's Kinect v1)
# took their smoothing from it, and at 1 frame serve's output jitter rose well past the Vicon's
OUTPUT_SMOOTH_S = 2.0 / 30.0
# A joint-frame the windows recovered and placed at least FILL_DISTANCE_M from the sensor's
# sample (or that had none) is the model's fill, not a measurement: the sensor errors it
# replaces (a broken leg, a lost hand) are decimetres, its noise centimetres
# (docs/SENSOR_ERRORS.md). Its frame-to-frame change is hand-over jitter, not motion, so the
# output smooths it with the wider half-width FILL_SMOOTH_S (4 frames at 30 Hz: 17 taps).
FILL_DISTANCE_M = 0.10
FILL_SMOOTH_S = 4.0 / 30.0


def next_window_end(end: int, window: int, hop: int, startup_hop: int, origin: int) -> int:
    """End (frame of a body's timeline) of the window after the one ending at ``end``.

    Windows end on the grid ``origin + k * hop`` (``origin``: the body's first window end
    ``L + 1``, less its phase, :func:`streamfix.streaming.bodies.hop_phase`). Until the body
    has a whole window of frames (``end < window``) a window also ends every
    ``startup_hop`` frames between grid points. Why: a body's first windows are short (the
    first holds ``L + 1`` frames) and consecutive short windows disagree more than whole
    ones; in between, each frame gets a window with more of its future, and two windows
    share ``L + 1 - startup_hop`` frames, a longer crossfade. The extra windows are short,
    so they cost little, and the grid after them is the same.
    """
    grid = origin + hop * ((end - origin) // hop + 1)
    return min(end + startup_hop, grid) if end < window else grid


def window_ends(n_frames: int, lookahead: int, hop: int, window: int | None = None,
                startup_hop: int | None = None) -> np.ndarray:
    """Ends of one body's windows (the engine's schedule, first window at ``L + 1``, phase
    0), every window that blends into a frame ``< n_frames``; ``startup_hop`` per
    :func:`next_window_end` (None: ``hop`` throughout)."""
    L, H = int(lookahead), int(hop)
    if window is None or startup_hop is None or startup_hop >= H:
        return np.arange(L + 1, int(n_frames) + L + 2, H)
    ends = [L + 1]
    while ends[-1] < int(n_frames) + L + 1:
        ends.append(next_window_end(ends[-1], int(window), H, int(startup_hop), L + 1))
    return np.asarray(ends)


def handover_weights(future: np.ndarray, lookahead: int, hop: int, crossfade: int | None = None,
                     hop_before: int | None = None) -> np.ndarray:
    """Overlap-add weight of a window for frames that saw ``future`` (>= 1) of its frames
    after them: a complementary crossfade over the ``K = L + 1 - H`` frames two
    consecutive windows share. ``hop``: frames to the next window (its ``K`` shapes
    the rise); ``hop_before``: frames from the previous one (the fall; None = ``hop``).

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

    def fade(h) -> tuple[np.ndarray, np.ndarray]:  # (K, F) for consecutive windows h frames apart
        K = np.maximum(int(lookahead) + 1 - np.asarray(h, dtype=np.int64), 1)
        return K, (K if crossfade is None else np.minimum(max(int(crossfade), 1), K))

    def smoothstep(z: np.ndarray) -> np.ndarray:
        z = np.clip(z, 0.0, 1.0)
        return z * z * (3.0 - 2.0 * z)

    K, F = fade(hop)
    Fb = F if hop_before is None else fade(hop_before)[1]
    rise = smoothstep((d - 0.5 - (K - F)) / F)
    fall = smoothstep((lookahead + 1.5 - d) / Fb)
    return 1e-3 + np.minimum(rise, fall)


def crossfade_frames(handover_s: float, rate_hz: float) -> int:
    """The crossfade ``handover_s`` (s) in frames at ``rate_hz`` (Hz), at least 1."""
    return max(1, int(round(float(handover_s) * float(rate_hz))))


def handover_frames(n_frames: int, lookahead: int, hop: int, crossfade: int, window: int | None = None,
                    startup_hop: int | None = None) -> np.ndarray:
    """``(T,)`` bool: the two frames around each window hand-over of the engine's blend.

    Windows end where :func:`window_ends` says (the engine's schedule for a body's
    timeline; ``window`` and ``startup_hop`` as in :func:`next_hop`, None = a regular
    hop) and frame ``n`` is blended from those with ``1 <= e - n <= L + 1`` by
    :func:`handover_weights`; the hand-over is the first frame whose largest weight belongs
    to a newer window than its predecessor's. That frame and the one before it are marked:
    where a crossfade that does not hide the change between two windows' solutions shows
    as a kink.
    """
    T = int(n_frames)
    out = np.zeros(max(T, 0), dtype=bool)
    L = int(lookahead)
    if T < 2:
        return out
    ends = window_ends(T, L, hop, window, startup_hop)  # every window that blends into a frame < T
    gaps = np.diff(ends)
    after = np.append(gaps, int(hop))[None, :]  # frames to each window's successor
    before = np.insert(gaps, 0, after[0, 0])[None, :]  # and from its predecessor
    d = ends[None, :] - np.arange(T)[:, None]  # (T, K)
    valid = (d >= 1) & (d <= L + 1)
    w = np.where(valid, handover_weights(np.clip(d, 1, L + 1), L, after, crossfade, before), -np.inf)
    has = valid.any(axis=1)
    dominant = np.where(has, np.argmax(w, axis=1), -1)
    switch = np.flatnonzero((dominant[1:] > dominant[:-1]) & has[1:] & has[:-1]) + 1
    out[switch] = True
    out[switch - 1] = True
    return out


def smooth_blended(values: np.ndarray, usable: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """The middle frames of ``values`` ``(n + 2h, J, 3)`` m smoothed by the symmetric
    kernel ``taps`` (``2 h + 1`` weights summing to 1).

    Why: each window's estimate is smooth, but the output is a crossfade of several
    windows' estimates, each near its newest edge on ``serve``'s schedule, plus the bone
    projection's per-frame corrections; what that leaves is frame-to-frame jitter. The
    engine uses :func:`streamfix.core.filters.twiced_binomial_taps` (zero gain at the
    Nyquist frequency, exact for quadratic motion, no lag). ``usable`` ``(n + 2h, J)``:
    frames and joints that hold a value; a middle frame whose taps are not all usable
    keeps its value. Returns ``(n, J, 3)``.
    """
    taps = np.asarray(taps, dtype=np.float64)
    h = len(taps) // 2
    x = np.asarray(values, dtype=np.float64)
    if h < 1 or x.shape[0] <= 2 * h:
        return x[h:x.shape[0] - h].copy()
    ok = np.asarray(usable, dtype=bool)
    n = x.shape[0] - 2 * h
    xs = np.where(ok[..., None], x, 0.0)
    out = np.zeros((n,) + x.shape[1:])
    complete = np.ones((n,) + ok.shape[1:], dtype=bool)
    for k, t in enumerate(taps):  # 2h + 1 shifted slices: one array op each
        out += t * xs[k:k + n]
        complete &= ok[k:k + n]
    return np.where(complete[..., None], out, x[h:h + n])
