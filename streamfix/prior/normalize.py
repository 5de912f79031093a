"""Normalisation of skeleton windows for the learned prior (numpy only; shared by training and run time).

The autoencoder sees a window ``Y`` (T, J, 3) that is

1. **root-relative**: the root trajectory ``r_t`` (Kinect v2: SpineBase) is subtracted
   from every joint of frame t (the paper's "hip joint fixed at the origin", Sec. 7.2);
2. **scale-normalised**: divided by the body-scale factor ``k`` = median over the
   window's observed *reference bones* of (observed bone length / the reference
   body's bone length). The reference bone lengths (metres) are the mean bone lengths
   of the training set and are stored in the model card (``normalisation.reference_bone_lengths_m``),
   so a normalised window is in "reference-body metres": a person 10 % taller than
   the training average is shrunk by 10 %.

The root of a frame where the root joint is not observed is interpolated linearly in
time from the frames where it is; if the root is missing from the whole window, the
midpoint of the hips is used, and failing that the mean of the observed joints. The
latent-space fit (``streamfix.prior.latent``) additionally estimates a constant
translation, which absorbs the bias of these fallbacks.

3. **facing-normalised** (when the card gives a ``facing_template``): the window is
   turned about the vertical axis y (Kinect camera space and BVH are both y-up) by the
   angle theta that best aligns its observed root-relative joints with the template
   pose (J, 3) (the mean Kinect v2 pose facing the sensor), a closed-form 2-D Procrustes
   problem in the x-z plane over all observed joint-frames:
   theta = atan2(S, C), S = sum(b_x a_z - b_z a_x), C = sum(b_x a_x + b_z a_z)
   (a = observed joint, b = template joint). Any subset of joints determines it, so it
   works with the joints the occlusion leaves.

    y = R_y(theta) (x - r_t) / k          x = R_y(theta)^T y k + r_t
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from streamfix.core.interpolate import observed_mask

__all__ = [
    "KINECT_V2_ROOT",
    "KINECT_V2_MIRROR",
    "KINECT_V2_LIMBS",
    "KINECT_V2_SCALE_BONES",
    "WindowNorm",
    "NormSpec",
    "root_trajectory",
    "body_scale",
    "normalise",
    "denormalise",
    "apply_norm",
    "rot_y",
    "facing_angle",
    "bone_lengths_median",
]

# Kinect v2 JointType indices (see streamfix.skeletons.KINECT_V2).
KINECT_V2_ROOT = 0  # SpineBase
_HIP_LEFT, _HIP_RIGHT = 12, 16

# Left/right swap used by mirroring augmentation: index j of the mirrored body is
# joint KINECT_V2_MIRROR[j] of the original (with x negated).
KINECT_V2_MIRROR = np.array(
    [0, 1, 2, 3, 8, 9, 10, 11, 4, 5, 6, 7, 16, 17, 18, 19, 12, 13, 14, 15, 20, 23, 24, 21, 22],
    dtype=np.intp,
)

# The paper's structured masks (Sec. 7.2, Table 3): arms are 6 joints, legs 4.
KINECT_V2_LIMBS = {
    "right_arm": (8, 9, 10, 11, 23, 24),
    "left_arm": (4, 5, 6, 7, 21, 22),
    "right_leg": (16, 17, 18, 19),
    "left_leg": (12, 13, 14, 15),
}

# Bones used for the body-scale estimate (child joint indices of KINECT_V2's bones): trunk
# and long limb bones only; hands, hand tips and thumbs are too short and too noisy on a Kinect.
KINECT_V2_SCALE_BONES = (1, 20, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18)


@dataclass
class WindowNorm:
    """What ``normalise`` did to one window: root trajectory (T, 3) m, scale factor k, rotation theta (rad) about y."""

    root: np.ndarray
    scale: float
    theta: float = 0.0


def _interp_rows(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Linear interpolation in time of ``values`` (T, C) over rows where ``valid`` (T,) is False; edges held."""
    if valid.all():
        return values.copy()
    t_valid = np.flatnonzero(valid)
    t = np.arange(values.shape[0])
    hi = np.minimum(np.searchsorted(t_valid, t), len(t_valid) - 1)  # first valid frame at or after t (edge: the last)
    lo = np.maximum(hi - (t_valid[hi] > t), 0)  # last valid frame at or before t (edge: the first)
    t0, t1 = t_valid[lo], t_valid[hi]
    a = ((t - t0) / np.maximum(t1 - t0, 1))[:, None]  # on and beyond the edges t0 == t1
    return values[t0] + a * (values[t1] - values[t0])


def _clean(positions: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(positions with unobserved joints set to 0, observed & finite): the validated input of the helpers below."""
    positions = np.asarray(positions, dtype=np.float64)
    observed = observed_mask(positions, observed)
    return np.where(observed[..., None], positions, 0.0), observed


def root_trajectory(
    positions: np.ndarray, observed: np.ndarray, root: int = KINECT_V2_ROOT, hips: tuple[int, int] = (_HIP_LEFT, _HIP_RIGHT)
) -> np.ndarray:
    """Root position per frame (T, 3) m: the root joint, interpolated where missing (see module doc)."""
    return _root_trajectory(*_clean(positions, observed), root, hips)


def _root_trajectory(clean: np.ndarray, observed: np.ndarray, root: int, hips: tuple[int, int]) -> np.ndarray:
    """``root_trajectory`` of ``_clean``'s output (no validation: the normalisation's hot path)."""
    if observed[:, root].any():
        return _interp_rows(clean[:, root], observed[:, root])
    hl, hr = hips
    if clean.shape[1] > max(hl, hr):
        both = observed[:, hl] & observed[:, hr]
        if both.any():
            return _interp_rows(0.5 * (clean[:, hl] + clean[:, hr]), both)
    count = observed.sum(axis=1)
    if not count.any():
        return np.zeros((clean.shape[0], 3))
    total = np.einsum("tjk->tk", clean)  # the sum over joints (cheaper than .sum(axis=1) over the middle axis)
    return _interp_rows(total / np.maximum(count, 1)[:, None], count > 0)


def bone_lengths_median(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Median length (m) of each bone over frames where both its joints are observed; NaN if never."""
    positions = np.asarray(positions, dtype=np.float64)
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    ends = bones.T.ravel()  # parents, then children: one gather each for both ends
    n_t, n_b = len(positions), len(bones)
    o, p = observed[:, ends].reshape(n_t, 2, n_b), positions[:, ends].reshape(n_t, 2, n_b, 3)
    both = o[:, 0] & o[:, 1]  # (T, B)
    d = p[:, 1] - p[:, 0]
    lengths = np.sqrt(np.einsum("tbk,tbk->tb", d, d))
    # median over the observed frames of each bone: sort with the unobserved ones last (np.nanmedian is much slower)
    n = both.sum(axis=0)
    if not len(lengths):
        return np.full(bones.shape[0], np.nan)
    srt = np.sort(np.where(both, lengths, np.inf), axis=0)
    cols = np.arange(bones.shape[0])
    lo, hi = np.maximum(n - 1, 0) // 2, np.minimum(n // 2, len(srt) - 1)
    return np.where(n > 0, 0.5 * (srt[lo, cols] + srt[hi, cols]), np.nan)


def _scale_bone_rows(bones: np.ndarray, reference_lengths: np.ndarray, scale_bones: tuple[int, ...]) -> np.ndarray:
    """Rows of ``bones`` that ``body_scale`` uses: child joint in ``scale_bones`` and a reference length."""
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    ref = np.asarray(reference_lengths, dtype=np.float64)
    return np.flatnonzero(np.isin(bones[:, 1], scale_bones) & (ref > 1e-6))


def body_scale(
    positions: np.ndarray,
    observed: np.ndarray,
    bones: np.ndarray,
    reference_lengths: np.ndarray,
    scale_bones: tuple[int, ...] = KINECT_V2_SCALE_BONES,
) -> float:
    """Body-scale factor k = median_b(L_b / L_ref_b) over observed reference bones; 1.0 if none seen."""
    rows = _scale_bone_rows(bones, reference_lengths, scale_bones)
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)[rows]
    return _body_scale(positions, observed, bones, np.asarray(reference_lengths, dtype=np.float64)[rows])


def _body_scale(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray, reference: np.ndarray) -> float:
    """``body_scale`` over the given (S, 2) scale bones and their (S,) reference lengths."""
    lengths = bone_lengths_median(positions, observed, bones)
    use = np.isfinite(lengths)
    if not use.any():
        return 1.0
    ratios = np.sort(lengths[use] / reference[use])
    k = 0.5 * float(ratios[(len(ratios) - 1) // 2] + ratios[len(ratios) // 2])  # the median (np.median costs more here)
    return min(max(k, 0.5), 2.0)


def rot_y(theta: float) -> np.ndarray:
    """Rotation matrix (3, 3) about the vertical y axis: (x, z) -> (c x + s z, -s x + c z)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _times(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``y @ m`` for (..., 3) rows and a (3, 3) matrix as one matrix product (a stacked matmul costs more)."""
    return (y.reshape(-1, 3) @ m).reshape(y.shape)


def facing_angle(y: np.ndarray, observed: np.ndarray, template: np.ndarray) -> float:
    """theta (rad) turning the observed joints of root-relative ``y`` (T, J, 3) onto ``template`` (J, 3) about y."""
    return _facing_angle(np.where(observed[..., None], y, 0.0), template)


def _facing_angle(a: np.ndarray, template: np.ndarray) -> float:
    """``facing_angle`` of a window ``a`` that is already 0 where unobserved."""
    b = np.asarray(template, dtype=np.float64)[:, ::2]  # (J, 2): x, z
    m = a.sum(axis=0)[:, ::2].T @ b  # m[i, l] = sum_tj a_i b_l, i, l in (x, z)
    s, c = float(m[1, 0] - m[0, 1]), float(m[0, 0] + m[1, 1])
    if abs(s) + abs(c) < 1e-9:
        return 0.0
    return float(np.arctan2(s, c))


def normalise(
    positions: np.ndarray,
    observed: np.ndarray,
    bones: np.ndarray,
    reference_lengths: np.ndarray,
    root: int = KINECT_V2_ROOT,
    template: np.ndarray | None = None,
    hips: tuple[int, int] = (_HIP_LEFT, _HIP_RIGHT),
    scale_bones: tuple[int, ...] = KINECT_V2_SCALE_BONES,
) -> tuple[np.ndarray, WindowNorm]:
    """Root-relative, scale- (and facing-) normalised window (T, J, 3), zeros where unobserved, and its ``WindowNorm``.

    ``root``, ``hips`` (fallback root) and ``scale_bones`` are joint indices of the window's
    layout (the canonical ones for the shipped prior, ``streamfix.canonical``)."""
    spec = NormSpec.of(bones, reference_lengths, root, template, hips, scale_bones)
    return spec.normalise(*_clean(positions, observed))


@dataclass(frozen=True, eq=False)
class NormSpec:
    """A model's constants of ``normalise``, resolved once (``Prior.norm_spec``): scale bones (S, 2) with
    their reference lengths (S,) m, root and fallback hip joints, facing template (J, 3) or None."""

    scale_bones: np.ndarray
    scale_reference: np.ndarray
    root: int
    hips: tuple[int, int]
    template: np.ndarray | None

    @classmethod
    def of(
        cls,
        bones: np.ndarray,
        reference_lengths: np.ndarray,
        root: int = KINECT_V2_ROOT,
        template: np.ndarray | None = None,
        hips: tuple[int, int] = (_HIP_LEFT, _HIP_RIGHT),
        scale_bones: tuple[int, ...] = KINECT_V2_SCALE_BONES,
    ) -> "NormSpec":
        """The spec of ``normalise``'s arguments (same meaning and defaults)."""
        rows = _scale_bone_rows(bones, reference_lengths, scale_bones)
        return cls(np.asarray(bones, dtype=np.intp).reshape(-1, 2)[rows],
                   np.asarray(reference_lengths, dtype=np.float64)[rows], int(root), tuple(int(h) for h in hips),
                   None if template is None else np.asarray(template, dtype=np.float64))

    def normalise(self, clean: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, WindowNorm]:
        """``normalise`` of a window with unobserved joints already 0 and ``observed`` finite-checked."""
        r = _root_trajectory(clean, observed, self.root, self.hips)
        k = _body_scale(clean, observed, self.scale_bones, self.scale_reference)
        y = (clean - r[:, None, :]) / k
        y[~observed] = 0.0  # the paper replaces unobserved rows of Y with 0 (Sec. 3)
        theta = 0.0
        if self.template is not None:
            theta = _facing_angle(y, self.template)
            y = _times(y, rot_y(theta).T)  # zero rows stay 0
        return y, WindowNorm(root=r, scale=k, theta=theta)


def apply_norm(positions: np.ndarray, norm: WindowNorm) -> np.ndarray:
    """``normalise``'s transform with a known ``WindowNorm`` (e.g. to map a training target the same way)."""
    y = (np.asarray(positions, dtype=np.float64) - norm.root[:, None, :]) / norm.scale
    return _times(y, rot_y(norm.theta).T) if norm.theta else y


def denormalise(y: np.ndarray, norm: WindowNorm) -> np.ndarray:
    """Inverse of ``normalise``: metres in the input's frame, (T, J, 3)."""
    y = np.asarray(y, dtype=np.float64)
    if norm.theta:
        y = _times(y, rot_y(norm.theta))
    return y * norm.scale + norm.root[:, None, :]
