"""A supporting foot stays on the floor: undo legs that a depth sensor folds up.

Why: measured against Vicon on UI-PRMD (Kinect v1), the sensor's worst failure is in
squats, lunges and sit-to-stand. As the pelvis goes down, the sensor folds *both* legs up
(feet rise by 30-60 cm while the real feet stay on the floor; knees end up above the
hips). Smoothing cannot undo that, and the error is large (knees/ankles 20-40 cm off).
A person who is not jumping always has a foot on the floor, so when *both* feet are off
the floor for longer than a jump's flight, the feet are wrong, not the person.

The model, per frame ``t`` (heights along the body's up direction ``u``, metres):

* heights, the floor and the anchors below come from a running median of the positions
  (``median_s``), so isolated wild samples cannot fake a lifted foot or a low floor;
* floor ``f`` = a low quantile of the lower foot's height over the context the caller
  has (the body's history and the window: the camera does not move);
* support loss ``g(t) = min(h_L(t), h_R(t)) - f``; correction weight
  ``w(t) = smoothstep((g - tol_lo) / (tol_hi - tol_lo))`` times how *folded* the legs
  are: the hips' height above the lower foot against the leg length (thigh + shin),
  full below ``folded_ratio[0]``, none above ``folded_ratio[1]``. The failure has both
  signs (feet up and legs tucked under the body); a person with straight legs seen
  against a floor estimated too low (the history held a drifting inferred leg) has
  only the first, and planting them then walked every later window into the ground.
  Runs shorter than ``min_run`` frames (jumps, stepping noise) are set to 0 unless
  they reach the end of the context (still going on);
* each ankle and foot is pulled, with weight ``w``, to where that foot last stood on
  the floor (``h - f < tol_lo / 2``, so not a frame where it was already rising; the
  next such frame if none came before; straight down to the floor if it never did);
* the knee is re-solved by two-bone inverse kinematics between the sensor's hip and
  the corrected ankle with the body's thigh and shin lengths, bending towards the toes
  (the horizontal ankle->foot direction: knees bend the way the feet point), and
  blended in with the same weight.

After the window is solved, :func:`smooth_planted` runs a longer zero-lag smoother over
the planted joints (knees, ankles, feet while planted). Why: a planted leg is a guess
built from the sensor's jittery hip (the knee's inverse kinematics amplifies it near a
straight leg) and a weight that follows the sensor's foot heights, so it carries jitter
that no real motion has; against Vicon on UI-PRMD the planted frames held most of the
clean output's excess jitter over the reference.

Arrays: positions ``(T, J, 3)`` metres, finite where used; ``legs`` ``(2, 4)`` joint
indices (hip, knee, ankle, foot) for left and right, see :mod:`streamfix.limbs`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import correlate1d

from .filters import odd_window, running_median
from .local_poly import fit_local_quadratic
from .points import point_norms

__all__ = [
    "SupportConfig",
    "up_direction",
    "estimate_floor",
    "support_weight",
    "two_bone_ik",
    "plant_supporting_feet",
    "smooth_planted",
]


@dataclass(frozen=True)
class SupportConfig:
    """Knobs of :func:`plant_supporting_feet` (metres, seconds)."""

    tol_lo_m: float = 0.08  # both feet above the floor by less than this: supported
    tol_hi_m: float = 0.20  # ... by more than this: fully corrected
    floor_quantile: float = 0.1
    min_run_s: float = 0.6  # shorter losses of support are jumps and hops (flight up to ~0.5 s), left alone
    median_s: float = 0.3  # heights, floor and anchors from a running median this long
    folded_ratio: tuple[float, float] = (0.6, 0.8)  # hips-to-lower-foot height / leg length: folded .. not
    max_wild_fraction: float = 0.35  # leg samples > wild_m from a 5-frame median: above this, do nothing
    wild_m: float = 0.10
    axis_snap_cos: float = 0.85  # snap the up direction to a coordinate axis within ~32 deg
    # a coordinate axis the trunk stands along (within ~20 deg) in some frames of the context is
    # up, however far it leans in the others (up_direction)
    upright_cos: float = 0.94
    upright_min_s: float = 0.2  # ... in at least this many seconds of frames
    # span of the smoother over planted joints (0 = none): a planted leg is a guess (anchored
    # foot, knee by IK from the sensor's hip) with no detail of its own, only the hip's jitter,
    # so it is smoothed over about a whole window; 1 s left UI-PRMD's lower body further
    # from Vicon and jitterier (benchmarks/bench_paired.py)
    planted_smooth_s: float = 2.5


def up_direction(positions: np.ndarray, legs: np.ndarray, shoulders: np.ndarray | None, snap_cos: float = 0.85,
                 upright_cos: float = 0.94, upright_min_frames: int = 6) -> np.ndarray:
    """Unit up vector ``(3,)`` from the trunk (mid-hips to mid-shoulders; mid-knees to
    mid-hips without shoulders) over the frames given.

    The camera does not move, the trunk does: in a squat or a lunge it leans 30-60 deg for
    seconds (UI-PRMD's deep squats reach 62 deg towards the camera), so a window at the
    bottom of one has a median trunk direction far from up. Sensors and mocap are y- or
    z-up, so: the signed coordinate axis the trunk stands along, within ``acos(upright_cos)``,
    in the most frames (at least ``upright_min_frames``: the person stood upright somewhere
    in the context, the body's history included); else the median trunk direction, snapped
    to the nearest axis when within ``acos(snap_cos)`` of it (a tilted camera: none is near).
    """
    hips = positions[:, legs[:, 0]].mean(axis=1)
    top = positions[:, shoulders].mean(axis=1) if shoulders is not None else hips
    bottom = hips if shoulders is not None else positions[:, legs[:, 1]].mean(axis=1)
    v = top - bottom
    n = np.linalg.norm(v, axis=1)
    ok = np.isfinite(n) & (n > 1e-6)
    if not ok.any():
        return np.array([0.0, 1.0, 0.0])
    d = v[ok] / n[ok, None]
    upright = np.concatenate([(d >= upright_cos).sum(axis=0), (-d >= upright_cos).sum(axis=0)])  # +x +y +z -x -y -z
    best = int(np.argmax(upright))
    if upright[best] >= max(1, upright_min_frames):
        return (1.0 if best < 3 else -1.0) * np.eye(3)[best % 3]
    u = np.median(d, axis=0)
    u = u / max(float(np.linalg.norm(u)), 1e-12)
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) >= snap_cos:
        u = np.sign(u[k]) * np.eye(3)[k]
    return u


def estimate_floor(foot_heights: np.ndarray, quantile: float = 0.1) -> float:
    """Floor height (m along up) from ``(T, 2)`` foot heights: a low quantile of the lower foot."""
    low = np.fmin(foot_heights[:, 0], foot_heights[:, 1])  # the lower foot; NaN only if both are
    low = low[np.isfinite(low)]
    return float(np.quantile(low, quantile)) if low.size else float("nan")


def _drop_short_runs(active: np.ndarray, min_run: int) -> np.ndarray:
    """``active`` ``(T,)`` bool with runs shorter than ``min_run`` cleared, except a run
    that reaches the last frame (it may still be going on)."""
    if min_run <= 1 or not active.any():
        return active
    a = np.concatenate([[False], active, [False]]).astype(np.int8)
    d = np.diff(a)
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    keep = ((ends - starts) >= min_run) | (ends == len(active))
    out = np.zeros_like(active)
    for s, e in zip(starts[keep], ends[keep]):  # a handful of runs per window
        out[s:e] = True
    return out


def support_weight(
    foot_heights: np.ndarray, floor: float, cfg: SupportConfig, rate_hz: float, folded: np.ndarray | None = None
) -> np.ndarray:
    """Correction weight ``(T,)`` in [0, 1]: how surely both feet are wrongly off the floor
    (times ``folded`` ``(T,)`` in [0, 1], how tucked up the legs are, when given)."""
    g = np.fmin(foot_heights[:, 0], foot_heights[:, 1]) - floor
    z = np.clip((g - cfg.tol_lo_m) / (cfg.tol_hi_m - cfg.tol_lo_m), 0.0, 1.0)
    w = np.where(np.isfinite(z), z * z * (3.0 - 2.0 * z), 0.0)
    if folded is not None:
        w = w * folded
    keep = _drop_short_runs(w > 0, int(round(cfg.min_run_s * rate_hz)))
    return np.where(keep, w, 0.0)


def two_bone_ik(root: np.ndarray, end: np.ndarray, l1: float, l2: float, bend: np.ndarray) -> np.ndarray:
    """Middle joint ``(T, 3)`` of a two-bone chain root-mid-end with lengths ``l1``, ``l2`` (m).

    The middle joint lies in the plane of the root->end line and ``bend`` ``(T, 3)``, on the
    side ``bend`` points to; an end out of reach (or too near) is treated as at the reach limit.
    """
    d = end - root
    L = np.linalg.norm(d, axis=1, keepdims=True)
    dn = d / np.maximum(L, 1e-9)
    Lc = np.clip(L, abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
    along = (l1 * l1 + Lc * Lc - l2 * l2) / (2.0 * Lc)  # law of cosines: distance from root along d
    radius = np.sqrt(np.maximum(l1 * l1 - along * along, 0.0))
    perp = bend - np.sum(bend * dn, axis=1, keepdims=True) * dn
    perp = perp / np.maximum(np.linalg.norm(perp, axis=1, keepdims=True), 1e-9)
    return root + along * dn + radius * perp


def _anchor_frames(on_floor: np.ndarray) -> np.ndarray:
    """For each frame, the last on-floor frame at or before it, else the next one, else -1."""
    T = len(on_floor)
    t = np.arange(T)
    last = np.maximum.accumulate(np.where(on_floor, t, -1))
    nxt = np.minimum.accumulate(np.where(on_floor, t, T)[::-1])[::-1]
    return np.where(last >= 0, last, np.where(nxt < T, nxt, -1))


def plant_supporting_feet(
    positions: np.ndarray,
    legs: np.ndarray,
    up: np.ndarray,
    rate_hz: float,
    leg_lengths: np.ndarray | None = None,
    cfg: SupportConfig = SupportConfig(),
    floor: float | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Pull both feet back onto the floor where the sensor lifted both (module doc).

    ``leg_lengths`` ``(2, 2)`` thigh and shin lengths (m) per side (None or not finite =
    medians of the input). ``floor`` None = :func:`estimate_floor` of the input. Returns the corrected
    positions ``(T, J, 3)``, the weight ``(T,)`` applied to the knee, ankle and foot of both
    legs, and the floor used. Joints other than knees, ankles and feet are not changed.
    """
    x = np.array(positions, dtype=np.float64, copy=True)
    # a running median ignores isolated wild samples (spikes, a corrupted coordinate):
    # a floor from raw heights sits on the lowest outliers and makes every foot look lifted.
    # Plain one-sided medians at the window's ends: a slope through a folding leg's samples
    # extrapolates the fold (detrended edges: UI-PRMD lower body error and seam both worse)
    # only the hips, ankles and feet are read from it: the other joints' medians were most of its cost
    ref = np.full_like(x, np.nan)
    need = np.unique(legs[:, [0, 2, 3]])
    ref[:, need] = running_median(x[:, need], odd_window(cfg.median_s, rate_hz), detrend_edges=False)
    heights = np.stack([ref[:, legs[s, 3]] @ up for s in range(2)], axis=1)  # (T, 2)
    # wild = far from a 5-frame median: isolated corruption, not a fast fold (feet rise
    # 50 cm in 0.5 s in a real squat failure, i.e. a few cm per frame)
    near = running_median(x[:, legs.ravel()], 5, detrend_edges=False)
    dev = point_norms(x[:, legs.ravel()] - near)
    if np.mean(dev[np.isfinite(dev)] > cfg.wild_m) > cfg.max_wild_fraction:
        # mostly wild samples (not a sensor's folded legs): no floor or anchor can be trusted
        return x, np.zeros(len(x)), float("nan")
    if floor is None:
        floor = estimate_floor(heights, cfg.floor_quantile)
    if not np.isfinite(floor):
        return x, np.zeros(len(x)), floor
    if leg_lengths is None or not np.all(np.isfinite(leg_lengths)):
        leg_lengths = np.array([[np.nanmedian(np.linalg.norm(x[:, legs[s, a + 1]] - x[:, legs[s, a]], axis=1))
                                 for a in range(2)] for s in range(2)])
    hips = ref[:, legs[:, 0]].mean(axis=1) @ up
    folded = (hips - np.fmin(heights[:, 0], heights[:, 1])) / max(float(np.mean(leg_lengths.sum(axis=1))), 1e-6)
    lo, hi = cfg.folded_ratio
    zf = np.clip((hi - folded) / max(hi - lo, 1e-12), 0.0, 1.0)
    fold = np.where(np.isfinite(zf), zf * zf * (3.0 - 2.0 * zf), 0.0)
    w = support_weight(heights, floor, cfg, rate_hz, fold)
    if not w.any():
        return x, w, floor
    wc = w[:, None]
    for s in range(2):
        hip, knee, ankle, foot = legs[s]
        anchor = _anchor_frames(heights[:, s] - floor < 0.5 * cfg.tol_lo_m)  # stood, not already rising
        have = (anchor >= 0)[:, None]
        at = np.maximum(anchor, 0)
        drop = (floor - heights[:, s])[:, None] * up  # no on-floor frame at all: straight down
        A, F = x[:, ankle], x[:, foot]
        A_new = A + wc * (np.where(have, ref[at, ankle], A + drop) - A)
        F_new = F + wc * (np.where(have, ref[at, foot], F + drop) - F)
        thigh, shin = float(leg_lengths[s, 0]), float(leg_lengths[s, 1])
        toe = F_new - A_new
        toe = toe - (toe @ up)[:, None] * up
        weak = np.linalg.norm(toe, axis=1) < 1e-3  # no foot joint: bend the way the sensor's knee does
        bend = np.where(weak[:, None], x[:, knee] - x[:, hip], toe)
        K_new = two_bone_ik(ref[:, hip], A_new, thigh, shin, bend)
        sel = (w > 0) & np.isfinite(K_new).all(axis=1) & np.isfinite(A_new).all(axis=1) & np.isfinite(F_new).all(axis=1)
        w = np.where(sel | (w <= 0), w, 0.0)  # no finite fix (a joint missing): untouched
        x[sel, knee] = x[sel, knee] + wc[sel] * (K_new[sel] - x[sel, knee])
        x[sel, ankle] = A_new[sel]
        x[sel, foot] = F_new[sel]
    return x, w, floor


def smooth_planted(positions: np.ndarray, weight: np.ndarray, rate_hz: float, span_s: float) -> np.ndarray:
    """``positions`` ``(T, J, 3)`` m with the joints foot support planted smoothed in time.

    ``weight`` ``(T, J)``: the plant's correction weight (0 = untouched). Each joint-frame
    takes a zero-lag local quadratic of span ``span_s`` (s) with share
    ``min(1, 2 * f)``, f = the fraction of planted frames within that span, so the
    smoother fades in and out around a planted stretch instead of switching on. Joints
    never planted are returned unchanged.
    """
    x = np.asarray(positions, dtype=np.float64)
    h = int(round(span_s * rate_hz / 2))
    cols = np.flatnonzero((np.asarray(weight) > 0).any(axis=0))
    if h < 1 or len(cols) == 0:
        return x
    T = x.shape[0]
    sub = x[:, cols]
    y = sub.reshape(T, -1)
    ok = np.isfinite(y)
    y0 = np.where(ok, y, 0.0)
    fit, _ = fit_local_quadratic(y0, ok.astype(np.float64), h)
    planted = (np.asarray(weight)[:, cols] > 0).astype(np.float64)
    share = np.clip(2.0 * correlate1d(planted, np.full(2 * h + 1, 1.0 / (2 * h + 1)), axis=0, mode="nearest"), 0.0, 1.0)
    share = np.repeat(share, 3, axis=1) * ok  # 0 where missing: NaN stays NaN
    out = x.copy()
    out[:, cols] = (y + share * (fit - y0)).reshape(sub.shape)
    return out
