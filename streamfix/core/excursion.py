"""Keep a model's gap fill near its continuity baseline, in the frame of the limb's anchor.

Not in the papers. A whole limb missing leaves PCA (trained on seconds of history) and
the prior to guess its pose from the rest of the body; on a nearly still limb that guess
can wander much further than simply holding the limb would, while a moving limb should
keep the model's motion. :func:`limit_excursion` shortens each fill's departure from a
continuity baseline (hold from the last observed sample; linear once the far end is
seen) to a multiple of the joint's own recent range of motion.

Both the baseline and the range of motion are taken relative to a per-frame
``reference`` (:func:`anchor_reference`: the nearest ancestor observed through the
window). Why: in world coordinates a walking person's missing foot "held" at its last
sample is left behind as the body moves on (the baseline itself is metres off), and its
world range of motion measures the walk, not the limb; relative to the hip the baseline
is the limb's last pose carried along by the body and the range is the leg's own swing.
"""
from __future__ import annotations

import numpy as np

from .interpolate import continuity_baseline
from .points import finite_points, point_norms

__all__ = ["EXCURSION_GAIN", "EXCURSION_HORIZON_S", "limit_excursion", "anchor_reference", "parents_from_bones",
           "bone_into", "travel_speed"]

EXCURSION_GAIN = 0.35
"""A fill may leave its continuity baseline (hold / linear) by at most this many times
the joint's own recent range of motion (see :func:`limit_excursion`)."""
EXCURSION_HORIZON_S = 1.0
"""Seconds of the joint's observed samples next to a gap that set its range of motion."""

_EPS = 1e-12


def travel_speed(positions: np.ndarray, observed: np.ndarray, rate_hz: float) -> float:
    """The body's net speed (m/s) from its first to its last observed frame.

    The mean displacement of the joints observed in both of those frames, over the time
    between them: the body travelling (walking, running), not its limbs moving in place,
    whose swings cancel over a span of seconds. 0 when fewer than two frames or no
    common joint are observed.
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool) & finite_points(x)
    seen = np.flatnonzero(obs.any(axis=1))
    if len(seen) < 2:
        return 0.0
    first, last = seen[0], seen[-1]
    common = obs[first] & obs[last]
    if not common.any():
        return 0.0
    shift = (x[last, common] - x[first, common]).mean(axis=0)
    return float(np.linalg.norm(shift) * float(rate_hz) / (last - first))


def bone_into(bones: np.ndarray, n_joints: int) -> np.ndarray:
    """``(J,)`` int: the index of the bone ending at each joint, -1 at a root. A joint two bones
    end at (MediaPipe's graph is no tree) takes the later-listed one, as :func:`parents_from_bones` does."""
    into = np.full(int(n_joints), -1, dtype=np.intp)
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    np.maximum.at(into, b[:, 1], np.arange(len(b), dtype=np.intp))
    return into


def parents_from_bones(bones: np.ndarray, n_joints: int) -> np.ndarray:
    """``(J,)`` int: each joint's parent from ``(parent, child)`` bone pairs (-1 = root; the
    later-listed bone where two end at a joint, :func:`bone_into`)."""
    b = np.asarray(bones, dtype=np.int64).reshape(-1, 2)
    into = bone_into(b, n_joints)
    return np.where(into >= 0, b[np.maximum(into, 0), 0] if len(b) else -1, -1).astype(np.int64)


def anchor_reference(positions: np.ndarray, observed: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """``(T, J, 3)`` m: per frame, the position each joint's fill is measured from.

    A joint's anchor is its nearest ancestor observed in every frame (itself when it is);
    joints with no such ancestor take the mean of the joints observed in every frame, or
    the origin when none is (world coordinates, the old behaviour).
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool) & finite_points(x)
    T, J = obs.shape
    parents = np.asarray(parents, dtype=np.int64)
    always = obs.all(axis=0)
    anchor = np.arange(J)
    # climb the tree until an always-observed joint or the root: at most J steps
    for _ in range(J):
        climb = ~always[anchor] & (parents[anchor] >= 0)
        if not climb.any():
            break
        anchor = np.where(climb, parents[anchor], anchor)
    ref = np.zeros((T, J, 3))
    if always.any():
        ref[:] = x[:, always].mean(axis=1, keepdims=True)
    has = always[anchor]
    ref[:, has] = x[:, anchor[has]]
    return ref


def limit_excursion(
    positions: np.ndarray,
    observed: np.ndarray,
    filled: np.ndarray,
    horizon: int,
    *,
    gain: float = EXCURSION_GAIN,
    floor: float = 0.0,
    reference: np.ndarray | None = None,
    ramp: int = 0,
) -> np.ndarray:
    """Keep a model fill within the joint's own recent range of motion of its continuity baseline.

    With ``y = positions - reference`` (``reference`` ``(T, J, 3)`` m, None = world
    coordinates): for each filled sample at frame ``t`` of joint ``j``, with ``p``/``n``
    the observed frames before/after its gap, baseline ``b(t) = y_p`` (far end not
    seen: hold) or ``y_p + (t - p)/(n - p) (y_n - y_p)`` (linear); scale ``A`` = RMS
    distance (metres) of the joint's observed ``y`` within ``horizon`` frames before
    ``p`` (and after ``n``) from ``y_p`` (``y_n``), the larger of the two. The fill's
    excursion ``d = y - b`` is shortened to at most ``gain * A + floor`` metres.
    ``positions`` ``(T, J, 3)`` m (filled), ``observed``/``filled`` ``(T, J)`` bool;
    observed samples are unchanged. ``ramp`` (frames, 0 = none): where the far end is not
    seen, the ``k``-th frame after ``p`` may leave by at most ``min(1, k / ramp)`` of that
    (a joint just lost cannot have gone far).
    """
    x = np.asarray(positions, dtype=np.float64)
    ref = np.zeros_like(x) if reference is None else np.asarray(reference, dtype=np.float64)
    if ref.shape != x.shape:
        raise ValueError(f"reference must have the positions' shape {x.shape}, got {ref.shape}")
    obs = np.asarray(observed, dtype=bool)
    fil = np.asarray(filled, dtype=bool) & ~obs
    if not fil.any() or not obs.any():
        return x.copy()
    y = x - ref
    T_len, J = obs.shape
    jj = np.arange(J)[None, :]
    base, prev, nxt = continuity_baseline(y, obs)
    hp, hn = prev >= 0, nxt < T_len
    pc, nc = np.clip(prev, 0, T_len - 1), np.clip(nxt, 0, T_len - 1)
    yo = np.where(obs[..., None], np.nan_to_num(y), 0.0)
    # prefix sums over observed samples: count, sum y, sum |y|^2 (row 0 = empty prefix)
    c0 = np.concatenate([np.zeros((1, J)), np.cumsum(obs, axis=0)])
    c1 = np.concatenate([np.zeros((1, J, 3)), np.cumsum(yo, axis=0)])
    c2 = np.concatenate([np.zeros((1, J)), np.cumsum((yo ** 2).sum(axis=2), axis=0)])

    def _rms(lo: np.ndarray, hi: np.ndarray, centre: np.ndarray) -> np.ndarray:
        # RMS |y_s - centre| over observed s in [lo, hi)
        n = c0[hi, jj] - c0[lo, jj]
        s1 = c1[hi, jj] - c1[lo, jj]
        s2 = c2[hi, jj] - c2[lo, jj]
        ss = s2 - 2.0 * (s1 * centre).sum(axis=-1) + n * (centre ** 2).sum(axis=-1)
        return np.sqrt(np.maximum(ss, 0.0) / np.maximum(n, 1))

    yp, yn = y[pc, jj], y[nc, jj]
    a_p = np.where(hp, _rms(np.maximum(pc - horizon, 0), pc + 1, yp), 0.0)
    a_n = np.where(hn, _rms(nc, np.minimum(nc + horizon + 1, T_len), yn), 0.0)
    cap = gain * np.maximum(a_p, a_n) + floor
    if ramp > 0:
        since = np.arange(T_len)[:, None] - prev
        cap = np.where(hp & ~hn, cap * np.minimum(1.0, since / float(ramp)), cap)
    d = y - base
    norm = point_norms(d)
    scale = np.where(norm > cap, cap / np.maximum(norm, _EPS), 1.0)
    use = fil & (hp | hn) & np.isfinite(norm)
    out = x.copy()
    out[use] = (ref + base + d * scale[..., None])[use]
    return out
