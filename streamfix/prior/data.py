"""Training data for the prior (numpy only): the held-out split, window sampling and augmentation.

A *take* (``streamfix.io.prior_takes.Take``) is one recording mapped onto the canonical
20 joints (``streamfix.canonical``), in metres, with an observation mask: BVH takes are
retargeted and fully observed; Kinect recordings keep only what the sensor tracked;
UI-PRMD Vicon markers give joint centres (``plug_in_gait_joints``).

Whole people/takes are held out for evaluation, never frames of a training take
(``HELD_OUT`` names takes or groups, e.g. ``uiprmd_s06`` = every repetition of UI-PRMD
subject 6). Batches draw sources by fixed shares (``SOURCE_SHARES``: UI-PRMD's 42 minutes
would otherwise drown the walking takes), takes within a source by duration. Windows are
sampled at the model rate (30 Hz) with

* **speed change**: the take is read at ``speed`` times its real pace (linear
  interpolation in time; a sample is observed only if both neighbours are);
* **rotation about the vertical axis** (y, both Kinect camera space and BVH are y-up);
* **left/right mirroring**: x negated and left/right joints swapped (``streamfix.canonical.mirrored``);
* **body proportions** (``proportion_sigma``): each bone scaled by its own factor, left and right
  alike (``rescale_bones``): the data holds few bodies (UI-PRMD has 10 people), users have others;
* **joint dropping** (the paper's partially observed training, Sec. 4.2 and
  Appendix A.3): random joint subsets, whole limbs, the joints a partial layout
  (COCO-17, Kinect v1, BlazePose) lacks, or runs of frames missing per joint. Frames
  outside a short take are unobserved padding.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from streamfix.canonical import (
    CANONICAL_BONES,
    CANONICAL_HIPS,
    CANONICAL_LIMBS,
    CANONICAL_MIRROR,
    CANONICAL_ROOT,
    CANONICAL_SCALE_BONES,
    LAYOUTS,
    mirrored,
)
from streamfix.io.prior_takes import Take, load_take, marker_take  # noqa: F401 (re-exported)

from .normalize import apply_norm, normalise, rot_y

#: ``normalise`` keyword arguments for canonical windows (root = pelvis, fallback = the hips, scale bones).
CANONICAL_NORM = {"root": CANONICAL_ROOT, "hips": CANONICAL_HIPS, "scale_bones": CANONICAL_SCALE_BONES}
# canonical joints each partial layout observes (training drops the others to teach those layouts)
_LAYOUT_COVERAGE = tuple(LAYOUTS[n].covered for n in ("coco17", "kinect_v1_uiprmd", "mediapipe_pose"))

__all__ = [
    "Take",
    "HELD_OUT",
    "MODEL_RATE_HZ",
    "load_take",
    "split_takes",
    "sample_window",
    "drop_joints",
    "mean_bone_lengths",
    "facing_template",
    "make_batch",
    "CANONICAL_NORM",
    "source_weights",
    "resample_masked",
    "cut_windows",
]

MODEL_RATE_HZ = 30.0
# Held-out takes (file stems): one CMU take, one Xia take, one Kinect recording.
HELD_OUT = ("131_02", "neutral_01_000", "Ges04_comehere", "uiprmd_s06")
#: Share of each training batch drawn from each source (renormalised over the sources present).
SOURCE_SHARES = {"uiprmd_vicon": 0.55, "uiprmd_kinect_v1": 0.15, "bvh": 0.12, "c3d_markers": 0.10, "kinect_v2": 0.08}


def split_takes(takes: list[Take], held_out: tuple[str, ...] = HELD_OUT) -> tuple[list[Take], list[Take]]:
    """(training, held-out) takes: a take is held out when its name or its group is in ``held_out``."""
    out = [t.name in held_out or t.group in held_out for t in takes]
    return [t for t, o in zip(takes, out) if not o], [t for t, o in zip(takes, out) if o]


def source_weights(takes: list[Take], shares: dict[str, float] | None = None) -> np.ndarray:
    """Probability of drawing each take: its source's share (``shares``, default ``SOURCE_SHARES``; 0.05 for a
    source not named), split by duration within the source."""
    shares = SOURCE_SHARES if shares is None else shares
    dur = np.array([t.duration_s for t in takes])
    src = [t.source for t in takes]
    share = {s: shares.get(s, 0.05) for s in set(src)}
    total = {s: dur[[x == s for x in src]].sum() for s in share}
    p = np.array([share[s] * d / total[s] for s, d in zip(src, dur)])
    return p / p.sum()


def facing_template(takes: list[Take], bones: np.ndarray, reference_lengths: np.ndarray) -> np.ndarray:
    """Mean root-relative, scale-normalised canonical pose (20, 3) of the Kinect v2 takes (subjects face the sensor)."""
    poses = []
    for t in takes:
        if t.source != "kinect_v2":
            continue
        y, _ = normalise(t.positions, t.observed, bones, reference_lengths, **CANONICAL_NORM)
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
    proportion_sigma: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """A (window, J, 3) m window and its (window, J) mask from ``take``, at ``rate_hz``, augmented.

    ``proportion_sigma`` > 0: each bone (left and right alike) is also scaled by exp(N(0, sigma))
    (``rescale_bones``): body proportions of people the data does not hold."""
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
            pos, mask = mirrored(pos, mask)
        if proportion_sigma > 0:
            pos = rescale_bones(pos, mask, np.exp(rng.normal(0.0, proportion_sigma, _N_BONE_KINDS))[_BONE_KIND])
    return pos, mask


def _bone_kinds() -> tuple[int, np.ndarray]:
    """(number of kinds, each canonical bone's kind): a bone and its mirror image (``CANONICAL_MIRROR``)
    are one kind, numbered in bone order, so that left and right scale alike."""
    bone_of_child = {int(c): k for k, (_, c) in enumerate(CANONICAL_BONES)}
    first = [min(k, bone_of_child[int(CANONICAL_MIRROR[c])]) for k, (_, c) in enumerate(CANONICAL_BONES)]
    kinds, kind = np.unique(first, return_inverse=True)
    return len(kinds), kind


_N_BONE_KINDS, _BONE_KIND = _bone_kinds()


def rescale_bones(positions: np.ndarray, observed: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """``positions`` (T, J, 3) m with canonical bone k scaled by ``scales[k]`` (``CANONICAL_BONES`` order).

    Each joint moves by its parent's displacement plus (s - 1) x its bone vector; a bone with an
    unobserved end keeps its vector (its child follows the parent). Unobserved joints stay 0."""
    disp = np.zeros_like(positions)
    for k, (p, c) in enumerate(CANONICAL_BONES):  # 19 bones, parents first
        both = (observed[:, p] & observed[:, c])[:, None]
        disp[:, c] = disp[:, p] + np.where(both, (scales[k] - 1.0) * (positions[:, c] - positions[:, p]), 0.0)
    return np.where(observed[..., None], positions + disp, 0.0)


def drop_joints(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Input mask after random dropping (paper Sec. 4.2 / App. A.3); the loss keeps the original ``mask``."""
    t_len, n_j = mask.shape
    keep = np.ones((t_len, n_j), dtype=bool)
    u = rng.random()
    if u < 0.1:
        pass
    elif u < 0.55:  # random subset of joints missing for the whole window (test OTP 100..40 %)
        k = rng.integers(1, int(0.6 * n_j) + 1)
        keep[:, rng.choice(n_j, size=k, replace=False)] = False
    elif u < 0.75:  # whole limbs (paper's structured masks, Table 3)
        limbs = list(CANONICAL_LIMBS.values())
        for i in rng.choice(len(limbs), size=rng.integers(1, 3), replace=False):
            keep[:, list(limbs[i])] = False
    elif u < 0.85:  # a partial layout (COCO-17, Kinect v1, BlazePose) and maybe a limb on top
        keep[:, ~_LAYOUT_COVERAGE[rng.integers(len(_LAYOUT_COVERAGE))]] = False
        if rng.random() < 0.5:
            keep[:, list(list(CANONICAL_LIMBS.values())[rng.integers(len(CANONICAL_LIMBS))])] = False
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
    shares: dict[str, float] | None = None,
    proportion_sigma: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(y_in, mask_in, y_target, mask_target), float32, normalised with the *input* window's root and scale.

    Takes are drawn by ``source_weights`` with ``shares`` (default ``SOURCE_SHARES``).
    """
    idx = rng.choice(len(takes), size=batch, p=source_weights(takes, shares))
    n_j = takes[0].positions.shape[1]
    y_in = np.zeros((batch, window, n_j, 3), np.float32)
    y_tg = np.zeros_like(y_in)
    m_in = np.zeros((batch, window, n_j), np.float32)
    m_tg = np.zeros_like(m_in)
    for b, i in enumerate(idx):  # batch items, not frames
        pos, mask = sample_window(takes[i], rng, window, augment=augment, proportion_sigma=proportion_sigma)
        keep = drop_joints(mask, rng)
        yi, norm = normalise(pos, keep, bones, reference_lengths, template=template, **CANONICAL_NORM)
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
    positions: np.ndarray, observed: np.ndarray, window: int = 64, hop: int | None = None, fill: float = np.nan
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows (W, window, J, 3) and masks (W, window, J) covering every frame, and their start frames (W,).

    Starts are 0, hop, 2*hop, ... with the last window aligned to the end; a take
    shorter than ``window`` becomes one window padded with unobserved frames.
    Unobserved samples of the windows are ``fill`` (the prior's input takes 0).
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
    pos = np.where(mask[..., None], pos, fill)
    return pos, mask, starts
