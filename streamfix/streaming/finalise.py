"""A body's frames whose clean value can no longer change, moved to the stream in one array pass.

A frame is final once every window that blends into it has been blended
(:mod:`~streamfix.streaming.overlap_add`). :func:`final_end` says how far a body's frames
are final; :func:`finalise_frames` turns that run of ring rows into output values,
recovered flags and confidences with a few array operations for the whole run, then hands
each frame to the stream's pending frames. Why a run: the offline engine finalises a
window's worth of frames at once (:class:`~streamfix.streaming.engine.StreamEngine`
without live output), where numpy calls frame by frame were a large part of a file's
cleaning time. The values do not depend on how the frames are grouped into runs.
"""
from __future__ import annotations

import numpy as np

from ..core.points import finite_points
from ..core.pose_bias import PoseBiasModel, remove_pose_bias
from ..frames import BodyFrame
from .bodies import RECOVERED_CONFIDENCE, Body, StreamState
from .bone_lengths import sample_clean_bones

__all__ = ["final_end", "finalise_frames"]


def final_end(body: Body, lookahead: int) -> int:
    """End (exclusive, timeline frames) of the body's frames that are final now.

    Frame ``n`` is final when frame ``n + L`` has arrived, the oldest unblended window
    ends after ``n + L + 1`` (it does not reach ``n``) and a blended window covers ``n``
    (a degraded hop can leave a gap); a body that is leaving has all its frames final
    once its last window is blended.
    """
    if body.ending:
        return body.final_upto if body.jobs else body.count
    end = min(body.count - lookahead, body.last_processed_end)
    if body.jobs:
        end = min(end, body.jobs[0].end - lookahead - 1)
    return max(body.final_upto, end)


def _rows(body: Body, n0: int, n1: int) -> slice | np.ndarray:
    """Ring rows of timeline frames ``n0 .. n1 - 1``: a slice (views) unless the run wraps."""
    k0 = n0 % body.cap
    if k0 + (n1 - n0) <= body.cap:
        return slice(k0, k0 + (n1 - n0))
    return np.arange(n0, n1) % body.cap


def finalise_frames(
    st: StreamState,
    body: Body,
    end: int,
    bones: np.ndarray,
    hop: int,
    *,
    learn_lengths: bool,
    live_output: bool,
    history: bool,
    pose_bias: PoseBiasModel | None = None,
    bias_alpha: float = 1.0,
) -> tuple[int, int]:
    """Finalise the body's frames ``body.final_upto .. end - 1`` into ``st.pending``.

    Each present frame's value is its smoothed blend (or the blend); joints no solved
    window reached take the live value. A joint is recovered where the sensor did not
    observe it or the windows that recovered it carry most of its weight; its confidence
    is the sensor's, :data:`~streamfix.streaming.bodies.RECOVERED_CONFIDENCE` where
    recovered, 0 without a position. ``learn_lengths``: file each output frame into the
    body's clean bone-length memory (:func:`~streamfix.streaming.bone_lengths.sample_clean_bones`;
    ``live_output``: and hand new lengths to the live path); ``history``: keep the output's
    observed samples in the body's history (solvers that train on it). ``pose_bias``: the
    learned sensor bias removed from the emitted values only
    (:func:`~streamfix.core.pose_bias.remove_pose_bias`, ``bias_alpha`` its smoothing gain,
    its state kept in ``body.bias_last``). Advances
    ``body.final_upto`` to ``end``; returns ``(joints recovered, joints given the live value)``.
    """
    n0 = body.final_upto
    count = end - n0
    if count <= 0:
        return 0, 0
    rows = _rows(body, n0, end)
    present = body.present[rows]
    recovered = fallback = 0
    frames = None
    if present.all():
        k_p = rows
    elif present.any():
        frames = np.arange(n0, end)[present]
        k_p = frames % body.cap
    else:
        k_p = None
    if k_p is not None:
        n_p = np.arange(n0, end) if frames is None else frames
        den = body.den[k_p]
        have = den > 0
        fresh = body.smooth_for[k_p] == n_p
        value = np.where(fresh[:, None, None], body.smooth[k_p], body.mean[k_p])
        valid = body.valid[k_p]
        if have.all():  # every joint has a window value (the usual case): no masking
            pos = value
            rec = ~valid | (body.recw[k_p] / den > 0.5)
        else:  # joints no solved window gave a value: the live one
            fallback = int((~have).sum())
            pos = np.where(have[..., None], value, body.live[k_p])
            recw = np.divide(body.recw[k_p], den, out=np.zeros_like(den), where=have)
            rec = np.where(have, ~valid | (recw > 0.5), body.live_rec[k_p] | ~valid)
        conf = np.where(rec, RECOVERED_CONFIDENCE, body.conf[k_p])
        finite = finite_points(pos)
        if not finite.all():
            conf = np.where(finite, conf, 0.0)
        emitted = pos
        if pose_bias is not None:
            emitted, body.bias_last = remove_pose_bias(pos, bones, pose_bias, bias_alpha, body.bias_last)
        bid = body.body_id
        g0 = body.g0
        handed = np.zeros(len(n_p), dtype=bool)  # frames still pending in the stream
        for i, n in enumerate(n_p.tolist()):
            pend = st.pending.get(g0 + n)
            if pend is None:
                continue
            pend.slots[bid] = BodyFrame(bid, emitted[i], conf[i], rec[i])
            pend.missing -= 1
            handed[i] = True
        if handed.any():
            recovered = int(rec[handed].sum())
            if learn_lengths:
                est = sample_clean_bones(body, pos[handed], bones, hop)
                if est is not None and live_output:
                    body.live_path.set_bone_lengths(est)
    if history:  # observed samples of the clean output; row = timeline frame (absent: NaN)
        cap = len(body.hist)
        skip = max(0, count - cap)  # a run longer than the history: only its newest frames stay
        if k_p is rows:  # every frame present
            block = np.where(rec[..., None], np.nan, pos)
        else:
            block = np.full((count,) + body.hist.shape[1:], np.nan)
            if k_p is not None:
                block[present] = np.where(rec[..., None], np.nan, pos)
        h0 = (body.hist_n + skip) % cap
        if h0 + count - skip <= cap:
            body.hist[h0:h0 + count - skip] = block[skip:]
        else:
            body.hist[(body.hist_n + np.arange(skip, count)) % cap] = block[skip:]
        body.hist_n += count
    body.final_upto = end
    return recovered, fallback
