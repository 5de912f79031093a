"""A body's clean values: each solved window folded into its frames by overlap-add, then
smoothed over time where the windows found sensor noise.

Operates on a :class:`~streamfix.streaming.bodies.Body`'s ring rows (``mean``, ``den``,
``recw``, ``noise``, ``smooth``); the weights and kernels are
:mod:`streamfix.streaming.blending`'s. The engine (:mod:`streamfix.streaming.engine`)
decides when a window is blended and when a frame is final.
"""
from __future__ import annotations

import numpy as np

from ..core.interpolate import neighbour_observations
from ..core.points import finite_points, point_norms
from .bodies import Body, Job
from .blending import FILL_DISTANCE_M, crossfade_frames, handover_weights, smooth_blended
from .config import EngineConfig

__all__ = ["blend_window", "closed_gaps", "fill_mask", "smooth_output"]


def blend_window(body: Body, job: Job, prev_end: int, cfg: EngineConfig,
                 output_taps: np.ndarray, fill_taps: np.ndarray) -> None:
    """Overlap-add: fold the window's solution into the frames it is due to, then smooth them.

    Window ``e`` contributes to frame ``n`` iff ``n < e <= n + L + 1`` or, when the hop
    was degraded beyond the lookahead, it is the first window covering ``n``
    (``prev_end <= n``). This makes each frame's value independent of when its
    windows finished (threaded and synchronous modes agree).

    A window that knows more about a sample than the older windows did drops what they
    blended there, and such windows blend with each other as usual (``body.informed_only``,
    so the sample keeps its crossfade at every hand-over). It knows more when it released
    the sample as the sensor's frozen guess (``job.released``): the older windows saw a
    shorter stretch of the frozen run, too short to judge, and kept the frozen pose as a
    measurement (on ``serve``'s 0.5 s lookahead, the first half second of every freeze); or
    when it saw the sample's gap end (the joint observed later in the window,
    :func:`closed_gaps`): the older windows could only extrapolate it, and on ``serve``'s
    0.5 s lookahead a blackout shorter than the lookahead kept much of their error
    (``eval --protocol blackout``'s ``streamfix_serve`` against the spline through both ends,
    ``benchmarks/results/pca.json``).
    """
    lo = max(job.start, body.final_upto, min(job.end - cfg.lookahead - 1, prev_end))
    if lo >= job.end:
        return
    crossfade = crossfade_frames(cfg.handover_s, cfg.rate_hz)
    w = handover_weights(job.end - np.arange(lo, job.end), cfg.lookahead, job.hop_after, crossfade, job.hop_before)
    x = job.result_pos[lo - job.start:]
    r = job.result_rec[lo - job.start:].astype(np.float64)
    rows = np.arange(lo, job.end) % body.cap
    finite = finite_points(x)
    wj = np.where(finite, w[:, None], 0.0)  # (n, J)
    informed = closed_gaps(body.valid[rows])  # the joint seen again by the window's end
    if job.released is not None:
        informed |= job.released[lo - job.start:]
    informed &= finite
    before = body.den[rows]
    fresh = informed & ~body.informed_only[rows]  # older windows that knew less: dropped
    if fresh.any():
        before = np.where(fresh, 0.0, before)
        body.recw[rows] = np.where(fresh, 0.0, body.recw[rows])
    body.informed_only[rows] = np.where(finite, informed, body.informed_only[rows])
    den = before + wj
    frac = np.divide(wj, den, out=np.zeros_like(wj), where=den > 0)
    mean = body.mean[rows]
    body.mean[rows] = mean + frac[..., None] * (np.where(finite[..., None], x, mean) - mean)
    body.recw[rows] = body.recw[rows] + wj * r
    body.den[rows] = den
    body.noise[rows] = body.noise[rows] + frac * (job.noise_share - body.noise[rows])
    smooth_output(body, lo, job.end, output_taps, fill_taps)


def closed_gaps(valid: np.ndarray) -> np.ndarray:
    """``(T, J)`` bool: samples without a sensor value whose joint has one later in the
    window (``valid`` ``(T, J)``): gaps the window saw end, which it bridges from both sides."""
    v = np.asarray(valid, dtype=bool)
    return ~v & (neighbour_observations(v)[1] < len(v))


def smooth_output(body: Body, lo: int, end: int, taps: np.ndarray, fill_taps: np.ndarray) -> None:
    """Smooth the blended values of frames ``lo .. end - 1`` (:func:`smooth_blended`,
    the twiced binomial ``taps`` of half-width ``output_smooth_s``; the model's fills,
    :func:`fill_mask`, with the wider ``fill_taps``).

    Run after each blend on the frames that window changed: a frame's smoothed value is
    the one computed after the last window that reaches it, from its final neighbours
    before it and the newest window's (provisional) values after it, so it depends on
    the windows' order only and adds no latency. Frames without ``h`` blended
    neighbours on both sides (a body's first and last frames) keep their value. The
    smoothing is weighted by the windows' ``noise_share`` (blended like the positions):
    what a window found to be sensor noise is smoothed; exact data (mocap, the paper's
    protocol), where it would only add bias, is left alone.
    """
    if len(taps) < 3:
        return
    frames = np.arange(lo, end)
    mid = frames % body.cap
    share = body.noise[mid][..., None]
    if not share.any():  # exact data: the blended values stand (no row holds a smoothed value)
        body.smooth_for[mid] = -1
        return
    mean = body.mean[mid]
    body.smooth[mid] = share * _smoothed(body, lo, end, taps) + (1.0 - share) * mean
    body.smooth_for[mid] = frames
    fill = fill_mask(body, mid) if len(fill_taps) > len(taps) else None
    if fill is not None and fill.any():
        wide = share * _smoothed(body, lo, end, fill_taps) + (1.0 - share) * mean
        body.smooth[mid] = np.where(fill[..., None], wide, body.smooth[mid])


def _smoothed(body: Body, lo: int, end: int, taps: np.ndarray) -> np.ndarray:
    """``(end - lo, J, 3)``: the blended values of frames ``lo .. end - 1`` smoothed by
    ``taps`` (:func:`smooth_blended`; neighbours not blended yet, or absent, leave a
    frame's value as it is)."""
    h = len(taps) // 2
    frames = np.arange(lo - h, end + h)
    rows = frames % body.cap
    have = (frames >= 0) & (frames < end) & body.present[rows]
    usable = have[:, None] & (body.den[rows] > 0)
    return smooth_blended(body.mean[rows], usable, taps)


def fill_mask(body: Body, rows: np.ndarray) -> np.ndarray:
    """``(n, J)`` bool: the model's fills among the body's ``rows``: joint-frames the
    windows mostly marked recovered and placed at least
    :data:`~streamfix.streaming.blending.FILL_DISTANCE_M` from the sensor's sample (or
    that had none). Their frame-to-frame changes are window hand-overs, not motion (on
    UI-PRMD, ``serve``'s jitter is mostly the legs the sensor lost), so they get the
    wider ``fill_smooth_s`` kernel; measurements, noisy or corrected by a few
    centimetres, keep the narrow one, so jitter on tracked joints is not traded for lag."""
    den = body.den[rows]
    with np.errstate(invalid="ignore"):
        near = point_norms(body.mean[rows] - body.raw[rows]) < FILL_DISTANCE_M  # NaN raw: not near
    return (body.recw[rows] > 0.5 * den) & (den > 0) & ~near
