"""Training data for the prior (numpy only): takes, the held-out split, window sampling and augmentation.

A *take* is one recording converted to the Kinect v2 joint layout, in metres, with an
observation mask: BVH takes are retargeted (``streamfix.io.retarget.bvh_to_kinect_v2``)
and fully observed; Kinect v2 recordings keep only **tracked** joints as observed
(inferred joints are the sensor's guesses, not data).

Whole takes are held out for evaluation, never frames of a training take
(``HELD_OUT``). Windows are sampled at the model rate (30 Hz) with

* **speed change**: the take is read at ``speed`` times its real pace (linear
  interpolation in time; a sample is observed only if both neighbours are);
* **rotation about the vertical axis** (y, both Kinect camera space and BVH are y-up);
* **left/right mirroring**: x negated and the Kinect left/right joints swapped
  (``KINECT_V2_MIRROR``);
* **joint dropping** (the paper's partially observed training, Sec. 4.2 and
  Appendix A.3): random joint subsets or whole limbs missing for the whole window,
  or random runs of frames missing per joint. Frames outside a short take are
  unobserved padding.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .normalize import KINECT_V2_LIMBS, KINECT_V2_MIRROR, apply_norm, normalise, rot_y

__all__ = [
    "Take",
    "HELD_OUT",
    "MODEL_RATE_HZ",
    "load_take",
    "load_takes",
    "split_takes",
    "sample_window",
    "drop_joints",
    "mean_bone_lengths",
    "facing_template",
    "make_batch",
    "resample_masked",
    "cut_windows",
]

MODEL_RATE_HZ = 30.0
# Held-out takes (file stems): one CMU take, one Xia take, one Kinect recording.
HELD_OUT = ("131_02", "neutral_01_000", "Ges04_comehere")


@dataclass
class Take:
    name: str
    positions: np.ndarray  # (N, J, 3) m, NaN where unobserved
    observed: np.ndarray  # (N, J) bool
    rate_hz: float
    source: str  # "bvh" or "kinect_v2"


def load_take(path: str | Path) -> Take:
    """One file as a Kinect v2 take: BVH retargeted (all observed), Kinect CSV with tracked joints observed."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        from streamfix.io.bvh import read_bvh
        from streamfix.io.retarget import bvh_to_kinect_v2

        motion = bvh_to_kinect_v2(read_bvh(path))
        observed = motion.observed.copy()
        source = "bvh"
    elif suffix == ".csv":
        from streamfix.io.kinect_csv import read_kinect_csv

        motion = read_kinect_csv(path)
        observed = motion.confidence >= 1.0  # tracked only
        source = "kinect_v2"
    else:
        raise ValueError(f"{path}: expected a .bvh or Kinect v2 .csv file, got {suffix!r}")
    if motion.n_joints != 25:
        raise ValueError(f"{path}: expected the 25 Kinect v2 joints, got {motion.n_joints}")
    positions = motion.positions.copy()
    positions[~observed] = np.nan
    return Take(path.stem, positions, observed, motion.rate_hz, source)


# CMU full-body marker set -> Kinect v2 joints (approximate joint positions from surface
# markers; documented so the approximation is visible): each Kinect joint is a weighted
# sum of markers, weights summing to 1.
_CMU_MARKERS_TO_KINECT = {
    "SpineBase": {"LFWT": 0.25, "RFWT": 0.25, "LBWT": 0.25, "RBWT": 0.25},  # pelvis centre
    "SpineMid": {"T10": 0.5, "STRN": 0.5},
    "SpineShoulder": {"C7": 0.5, "CLAV": 0.5},
    "Neck": {"C7": 0.35, "CLAV": 0.35, "LFHD": 0.075, "RFHD": 0.075, "LBHD": 0.075, "RBHD": 0.075},
    "Head": {"LFHD": 0.25, "RFHD": 0.25, "LBHD": 0.25, "RBHD": 0.25},
    # hip joint centre: pelvis centre + 0.325 (same-side waist midpoint - other-side midpoint), ~8 cm
    # (then SpineBase and both hips are moved 8 cm down the trunk: waist markers sit on the iliac crest)
    "HipLeft": {"LFWT": 0.4125, "LBWT": 0.4125, "RFWT": 0.0875, "RBWT": 0.0875},
    "HipRight": {"RFWT": 0.4125, "RBWT": 0.4125, "LFWT": 0.0875, "LBWT": 0.0875},
    "KneeLeft": {"LKNE": 1.0}, "KneeRight": {"RKNE": 1.0},
    "AnkleLeft": {"LANK": 1.0}, "AnkleRight": {"RANK": 1.0},
    "FootLeft": {"LTOE": 0.5, "LMT5": 0.5}, "FootRight": {"RTOE": 0.5, "RMT5": 0.5},
    "ShoulderLeft": {"LSHO": 1.0}, "ShoulderRight": {"RSHO": 1.0},
    "ElbowLeft": {"LELB": 1.0}, "ElbowRight": {"RELB": 1.0},
    "WristLeft": {"LWRA": 0.5, "LWRB": 0.5}, "WristRight": {"RWRA": 0.5, "RWRB": 0.5},
    # hand = 60 % and hand tip = 160 % of the way from the wrist centre to the knuckle marker
    "HandLeft": {"LWRA": 0.2, "LWRB": 0.2, "LFIN": 0.6}, "HandRight": {"RWRA": 0.2, "RWRB": 0.2, "RFIN": 0.6},
    "HandTipLeft": {"LWRA": -0.3, "LWRB": -0.3, "LFIN": 1.6}, "HandTipRight": {"RWRA": -0.3, "RWRB": -0.3, "RFIN": 1.6},
    # thumb: from the thumb-side wrist marker 80 % of the wrist-to-knuckle vector
    "ThumbLeft": {"LWRA": 0.6, "LWRB": -0.4, "LFIN": 0.8}, "ThumbRight": {"RWRA": 0.6, "RWRB": -0.4, "RFIN": 0.8},
}


def marker_take(path: str | Path) -> Take | None:
    """A CMU full-body marker C3D as a Kinect v2 take (``_CMU_MARKERS_TO_KINECT``), z-up turned y-up; None if not that marker set."""
    from streamfix.io.c3d import read_c3d
    from streamfix.skeletons import KINECT_V2

    path = Path(path)
    motion = read_c3d(path)
    names = {n.split(":")[-1].upper(): i for i, n in enumerate(motion.skeleton.joint_names)}
    needed = {m for w in _CMU_MARKERS_TO_KINECT.values() for m in w}
    if not needed <= set(names):
        return None
    weights = np.zeros((KINECT_V2.n_joints, motion.n_joints))
    for joint, wts in _CMU_MARKERS_TO_KINECT.items():
        for marker, wgt in wts.items():
            weights[KINECT_V2.index(joint), names[marker]] += wgt
    pos = np.einsum("km,tmc->tkc", weights, np.nan_to_num(motion.positions))
    trunk = pos[:, KINECT_V2.index("SpineShoulder")] - pos[:, KINECT_V2.index("SpineBase")]
    down = -trunk / np.maximum(np.linalg.norm(trunk, axis=-1, keepdims=True), 1e-9)
    for name in ("SpineBase", "HipLeft", "HipRight"):
        pos[:, KINECT_V2.index(name)] += 0.08 * down
    used = np.abs(weights) > 0
    observed = (motion.observed[:, None, :] | ~used[None]).all(axis=2)
    pos = pos[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # z-up -> y-up, right-handed
    pos[~observed] = np.nan
    return Take(path.stem, pos, observed, motion.rate_hz, "c3d_markers")


def load_takes(data_dir: str | Path, include_markers: bool = False) -> list[Take]:
    """Every BVH under ``cmu_bvh``/``xia_bvh``, every CSV under ``kinect_v2`` and (``include_markers``)
    every CMU full-body marker C3D under ``c3d`` of ``data_dir``, sorted by name within each kind.

    Markers are off by default: with them (85_02 + 135_02, +49 s of motion) the held-out
    D(E(Y)) improved (OTP 50 %: 16.2 -> 15.5 cm on dropped joints) but D(z*) got worse
    (11.0 -> 13.3 cm), so the shipped model is trained without them."""
    data_dir = Path(data_dir)
    paths = sorted(data_dir.glob("*_bvh/*.bvh")) + sorted(data_dir.glob("kinect_v2/*.csv"))
    if not paths:
        raise FileNotFoundError(f"no *_bvh/*.bvh or kinect_v2/*.csv files under {data_dir}")
    takes = [load_take(p) for p in paths]
    if include_markers:
        for p in sorted(data_dir.glob("c3d/*.c3d")):
            t = marker_take(p)
            if t is not None:
                takes.append(t)
    return takes


def split_takes(takes: list[Take], held_out: tuple[str, ...] = HELD_OUT) -> tuple[list[Take], list[Take]]:
    train = [t for t in takes if t.name not in held_out]
    test = [t for t in takes if t.name in held_out]
    return train, test


def facing_template(takes: list[Take], bones: np.ndarray, reference_lengths: np.ndarray) -> np.ndarray:
    """Mean root-relative, scale-normalised pose (J, 3) of the Kinect v2 takes (subjects face the sensor)."""
    poses = []
    for t in takes:
        if t.source != "kinect_v2":
            continue
        y, _ = normalise(t.positions, t.observed, bones, reference_lengths)
        poses.append(np.where(t.observed[..., None], y, np.nan))
    if not poses:
        raise ValueError("a facing template needs at least one Kinect v2 take (subjects facing the sensor)")
    with np.errstate(all="ignore"):
        return np.nan_to_num(np.nanmean(np.concatenate(poses), axis=0))


def mean_bone_lengths(takes: list[Take], bones: np.ndarray) -> np.ndarray:
    """Reference bone lengths (m): per take the median observed length, then the mean over takes."""
    from .normalize import bone_lengths_median

    per_take = np.stack([bone_lengths_median(t.positions, t.observed, bones) for t in takes])
    with np.errstate(all="ignore"):
        return np.nanmean(per_take, axis=0)


def sample_window(
    take: Take,
    rng: np.random.Generator,
    window: int = 64,
    rate_hz: float = MODEL_RATE_HZ,
    speed_range: tuple[float, float] = (0.7, 1.4),
    augment: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """A (window, J, 3) m window and its (window, J) mask from ``take``, at ``rate_hz``, augmented."""
    lo, hi = speed_range
    speed = float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) if augment else 1.0
    step = speed * take.rate_hz / rate_hz  # source frames per output frame
    n = take.positions.shape[0]
    span = step * (window - 1)
    if span <= n - 1:
        start = rng.uniform(0.0, n - 1 - span)
    else:  # short take: place it inside the window, the rest is unobserved padding
        start = rng.uniform(n - 1 - span, 0.0)
    f = start + step * np.arange(window)
    inside = (f >= 0) & (f <= n - 1)
    fc = np.clip(f, 0, n - 1)
    i0 = np.floor(fc).astype(np.intp)
    i1 = np.minimum(i0 + 1, n - 1)
    w = (fc - i0)[:, None, None]
    p0, p1 = take.positions[i0], take.positions[i1]
    pos = np.where(w > 0, (1 - w) * p0 + w * np.nan_to_num(p1), p0)
    mask = take.observed[i0] & (take.observed[i1] | (w[..., 0] == 0)) & inside[:, None]
    pos = np.where(mask[..., None], pos, 0.0)
    if augment:
        pos = pos @ rot_y(rng.uniform(-np.pi, np.pi)).T
        if rng.random() < 0.5:
            pos = pos[:, KINECT_V2_MIRROR] * np.array([-1.0, 1.0, 1.0])
            mask = mask[:, KINECT_V2_MIRROR]
    return pos, mask


def drop_joints(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Input mask after random dropping (paper Sec. 4.2 / App. A.3); the loss keeps the original ``mask``."""
    t_len, n_j = mask.shape
    keep = np.ones((t_len, n_j), dtype=bool)
    u = rng.random()
    if u < 0.1:
        pass
    elif u < 0.6:  # random subset of joints missing for the whole window (test OTP 100..40 %)
        k = rng.integers(1, int(0.6 * n_j) + 1)
        keep[:, rng.choice(n_j, size=k, replace=False)] = False
    elif u < 0.8:  # whole limbs (paper's structured masks, Table 3)
        limbs = list(KINECT_V2_LIMBS.values())
        for i in rng.choice(len(limbs), size=rng.integers(1, 3), replace=False):
            keep[:, list(limbs[i])] = False
    else:  # runs of missing frames per joint (occlusions)
        for j in rng.choice(n_j, size=rng.integers(1, n_j // 2), replace=False):
            length = rng.integers(5, t_len + 1)
            s = rng.integers(0, t_len - length + 1)
            keep[s : s + length, j] = False
    return mask & keep


def make_batch(
    takes: list[Take],
    rng: np.random.Generator,
    batch: int,
    bones: np.ndarray,
    reference_lengths: np.ndarray,
    window: int = 64,
    augment: bool = True,
    template: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(y_in, mask_in, y_target, mask_target), float32, normalised with the *input* window's root and scale.

    Takes are drawn with probability proportional to their duration.
    """
    dur = np.array([t.positions.shape[0] / t.rate_hz for t in takes])
    idx = rng.choice(len(takes), size=batch, p=dur / dur.sum())
    n_j = takes[0].positions.shape[1]
    y_in = np.zeros((batch, window, n_j, 3), np.float32)
    y_tg = np.zeros_like(y_in)
    m_in = np.zeros((batch, window, n_j), np.float32)
    m_tg = np.zeros_like(m_in)
    for b, i in enumerate(idx):  # batch items, not frames
        pos, mask = sample_window(takes[i], rng, window, augment=augment)
        keep = drop_joints(mask, rng)
        yi, norm = normalise(pos, keep, bones, reference_lengths, template=template)
        y_in[b] = yi
        m_in[b] = keep
        y_tg[b] = np.where(mask[..., None], apply_norm(pos, norm), 0.0)
        m_tg[b] = mask
    return y_in, m_in, y_tg, m_tg


def resample_masked(
    positions: np.ndarray, observed: np.ndarray, rate_in: float, rate_out: float
) -> tuple[np.ndarray, np.ndarray]:
    """Linear resampling in time from ``rate_in`` to ``rate_out`` Hz over the same duration.

    A resampled sample is observed only if both source neighbours are (or it falls
    exactly on an observed source frame). Returns ((T', J, 3) m, NaN where unobserved; (T', J) bool).
    """
    positions = np.asarray(positions, dtype=np.float64)
    observed = np.asarray(observed, dtype=bool) & np.isfinite(positions).all(axis=-1)
    n = positions.shape[0]
    if n == 0 or rate_in == rate_out:
        return positions.copy(), observed.copy()
    n_out = int(np.floor((n - 1) * rate_out / rate_in + 1e-9)) + 1
    f = np.arange(n_out) * (rate_in / rate_out)
    i0 = np.minimum(np.floor(f).astype(np.intp), n - 1)
    i1 = np.minimum(i0 + 1, n - 1)
    w = f - i0
    exact = w < 1e-9
    mask = observed[i0] & (observed[i1] | exact[:, None])
    p0 = np.nan_to_num(positions[i0])
    p1 = np.nan_to_num(positions[i1])
    out = (1 - w)[:, None, None] * p0 + w[:, None, None] * p1
    out[~mask] = np.nan
    return out, mask


def cut_windows(
    positions: np.ndarray, observed: np.ndarray, window: int = 64, hop: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows (W, window, J, 3) and masks (W, window, J) covering every frame, and their start frames (W,).

    Starts are 0, hop, 2*hop, ... with the last window aligned to the end; a take
    shorter than ``window`` becomes one window padded with unobserved frames.
    """
    hop = window if hop is None else hop
    n = positions.shape[0]
    if n >= window:
        starts = list(range(0, n - window + 1, hop))
        if starts[-1] != n - window:
            starts.append(n - window)
    else:
        starts = [0]
    starts = np.asarray(starts, dtype=np.intp)
    idx = starts[:, None] + np.arange(window)[None, :]
    valid = idx < n
    idx = np.minimum(idx, n - 1)
    pos = positions[idx]
    mask = observed[idx] & valid[..., None]
    pos = np.where(mask[..., None], pos, np.nan)
    return pos, mask, starts
