"""Bone-length isometry of Yang et al. (2019): Eq. (5), (16)-(20).

Positions here are ``(T, S, 3)`` in metres (``S`` joints); bones ``(B, 2)`` int
(parent, child); bone lengths ``(B,)`` metres.

Residual (Eq. 5/16), per frame t and bone h = (i, j):
    r_th(N) = d^2(n_i^t, n_j^t) - l_h^2,     E_iso(N) = ||F(N)||^2.
Jacobian: with u_th = n_i^t - n_j^t,  dr_th/dn_i^t = 2 u_th,  dr_th/dn_j^t = -2 u_th.
J is block diagonal over frames (frame t's residuals depend only on frame t), so
J^T J is block diagonal with ``3S x 3S`` blocks and the Gauss-Newton step of
Eq. (20) splits into T independent systems, solved here in one batched call.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.linalg.lapack import dpbsv as _pbsv
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

from . import kernels
from .points import point_norms
from .robust_stats import nanmedian

__all__ = [
    "bone_length_deviations",
    "bone_vectors",
    "bone_lengths_per_frame",
    "estimate_bone_lengths",
    "symmetric_lengths",
    "thrown_twins",
    "seen_bone_lengths",
    "TWIN_MAX_RATIO",
    "TWIN_MAX_EXCESS_M",
    "TWIN_MIN_M",
    "isometry_residual",
    "isometry_jacobian",
    "incidence_matrix",
    "gauss_newton_step",
]


def _bones(bones: np.ndarray, n_joints: int) -> np.ndarray:
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if b.size and (b.min() < 0 or b.max() >= n_joints):
        raise ValueError(f"bones must index {n_joints} joints, got indices {b.min()}..{b.max()}")
    return b


def incidence_matrix(bones: np.ndarray, n_joints: int) -> np.ndarray:
    """``(B, S)`` matrix M with +1 at the parent and -1 at the child: u = M n."""
    b = _bones(bones, n_joints)
    m = np.zeros((len(b), n_joints))
    m[np.arange(len(b)), b[:, 0]] = 1.0
    m[np.arange(len(b)), b[:, 1]] = -1.0
    return m


def bone_vectors(positions: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """``(T, B, 3)`` vectors u = n_parent - n_child (metres)."""
    p = np.asarray(positions, dtype=np.float64)
    b = _bones(bones, p.shape[-2])
    return p[..., b[:, 0], :] - p[..., b[:, 1], :]


def bone_lengths_per_frame(positions: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """``(T, B)`` Euclidean bone lengths d(n_i^t, n_j^t) in metres (NaN if an end is NaN)."""
    return point_norms(bone_vectors(positions, bones))


def _shorth_mode(values: np.ndarray, fraction: float) -> np.ndarray:
    """Per column, the middle of the shortest interval holding ``fraction`` of the finite values.

    ``values`` (T, B) with NaN = no sample. A mode estimator ("shorth"): with clean
    frames agreeing on one length and corrupted frames spread out, the densest
    interval sits on the clean length even when most frames are corrupted (where a
    median is dragged off). Vectorised over columns. Columns without samples -> NaN.
    """
    if kernels.COMPILED and values.ndim == 2:  # the same values, one compiled pass per column
        return kernels.shorth_mode(values, fraction)
    v = np.sort(values, axis=0)                       # NaN sort last
    n = np.isfinite(v).sum(axis=0)                    # (B,)
    h = np.maximum(np.ceil(fraction * n).astype(np.intp), 1)
    idx = np.arange(v.shape[0])[:, None]
    hi = np.minimum(idx + h[None, :] - 1, v.shape[0] - 1)
    width = np.take_along_axis(v, hi, axis=0) - v
    width[(idx + h[None, :] > n[None, :]) | ~np.isfinite(width)] = np.inf
    start = np.argmin(width, axis=0)                  # (B,)
    mid = np.minimum(start + (h - 1) // 2, v.shape[0] - 1)
    out = v[mid, np.arange(v.shape[1])]
    out[n == 0] = np.nan
    return out


def _cluster_median(values: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """Per column of ``values`` ``(T, B)`` (NaN = none), the median of the values within
    ``radius`` of ``centre`` ``(B,)``; NaN where there are none."""
    with np.errstate(invalid="ignore"):
        near = np.abs(values - centre[None, :]) <= radius
    return nanmedian(np.where(near, values, np.nan), axis=0)


DENSEST_HALF_WIDTH_M = 0.005
"""Half-width (m) of the window whose sample count :func:`densest_mode` maximises. Wide
enough to weigh a cluster of a sensor's pose-dependent lengths by its samples, narrow
enough that samples scattered by corruption do not add up to a peak: at 1 cm the paper
protocol's spikes (20 % of entries) pulled ``serve``'s lengths off and raised its clean
error (``tests/test_e2e_quality.py``); at 3 mm the KERAAL case below went
back to the smaller cluster (``tests/test_bone_lengths_real.py``)."""


def densest_mode(values: np.ndarray, half_width_m: float = DENSEST_HALF_WIDTH_M) -> np.ndarray:
    """Per column of ``values`` ``(T, B)`` (NaN = no sample), the sample with the most samples
    within ``half_width_m`` of it (ties: the middle one of the tied samples, in sorted
    order); NaN for a column without samples.

    Why not the shorth (the narrowest interval holding a fixed share of the samples): a
    sensor's bone length is often bimodal with the pose, and the shorth sits on the
    tighter cluster, not the larger one. On the KERAAL recording the right forearm has
    two clusters, the smaller and tighter one 2 cm short of the Vicon's length; the 10 %
    shorth chose it and the cleaner moved the elbow to shorten the forearm. Corrupted
    samples spread over decimetres still lose to a cluster of clean ones. The numpy
    reference of the compiled :func:`streamfix.core.kernels.length_mode_with_support` (a
    loop over the columns, bones, each a sorted search).
    """
    v = np.asarray(values, dtype=np.float64)
    out = np.full(v.shape[1], np.nan)
    for b in range(v.shape[1]):
        s = np.sort(v[:, b][np.isfinite(v[:, b])])
        if not len(s):
            continue
        count = np.searchsorted(s, s + half_width_m, side="right") - np.searchsorted(s, s - half_width_m, side="left")
        tied = np.flatnonzero(count == count.max())
        out[b] = s[tied[len(tied) // 2]]
    return out


def length_mode_with_support(
    samples: np.ndarray, half_width_m: float = DENSEST_HALF_WIDTH_M, tolerance_m: float = 0.005,
    refine_m: float | None = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Robust bone lengths of ``samples`` ``(T, B)`` metres (NaN = no sample) and their support.

    The densest mode (:func:`densest_mode`, the length most samples agree on to within
    ``half_width_m``) finds the cluster the clean samples form; with ``refine_m`` the
    estimate is then the median of the samples within ``refine_m`` of that mode (None:
    the mode itself). Why both: the mode ignores corrupted samples however many there
    are, but it rests on the samples of a narrow window only, so under sensor noise on
    every sample (temporally correlated: few independent samples in a short history) it
    wanders by several millimetres; the median of the whole clean cluster does not, and
    corrupted samples outside the cluster still do not count. The radius: about twice the
    spread of a clean bone's samples (Kinect's own length variation and sensor noise
    along the bone, 1-1.5 cm); measured by ``benchmarks/bench_sensor.py``,
    ``bench_paired.py`` and the Kinect files of ``bench_accuracy.py`` (3 cm was a little
    better on the simulated noise, 1 cm on the real Kinect recordings' jitter).

    Returns ``(lengths (B,), support (B,) int)``: ``support`` counts the samples within
    ``tolerance_m`` of each estimate. A mode found from a handful of frames can sit on
    two corrupted samples that happen to agree; callers use the support to decide
    whether to trust it (measured on CMU 131 at 20 % corruption: the first 16-frame
    window of a stream gave a 0 m bone a sizeable length from 2 agreeing samples).
    """
    values = np.asarray(samples, dtype=np.float64)
    if kernels.COMPILED and values.ndim == 2:  # the same values from one sort per column
        return kernels.length_mode_with_support(values, half_width_m, tolerance_m, refine_m)
    lengths = densest_mode(values, half_width_m)
    if refine_m is not None and values.size and values.ndim == 2:
        refined = _cluster_median(values, lengths, float(refine_m))
        lengths = np.where(np.isfinite(refined), refined, lengths)
    with np.errstate(invalid="ignore"):
        support = (np.abs(values - lengths[None, :]) <= tolerance_m).sum(axis=0)
    return lengths, support


TWIN_MAX_RATIO = 2.0
"""A bone estimated longer than this times its left/right twin's..."""
TWIN_MAX_EXCESS_M = 0.25
"""...and by more than this (m) is no person's: a sensor's failure, not the body's. Loose on
purpose: Kinect v1's collar bones (UI-PRMD) differ from their twins by up to 2x and 14 cm over
a stream's first 2 s, and taking the shorter one there raised the debiased error against
Vicon; a joint read at the wall's depth makes its bone decimetres to metres longer."""
TWIN_MIN_M = 0.03
"""...unless the twin itself is shorter than this (m): a collapsed twin (an inferred joint put on
its parent) says nothing of the bone's length."""


def thrown_twins(lengths: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """``(B,)`` bool: bones whose estimate ``lengths`` ``(B,)`` m exceeds their left/right twin's
    (``mirror`` ``(B,)``, each bone's counterpart) by ``TWIN_MAX_RATIO`` times and
    ``TWIN_MAX_EXCESS_M``, the twin being at least ``TWIN_MIN_M``: an estimate a sensor's thrown
    joint made (the caller takes the twin's). ValueError when ``mirror`` does not match."""
    est = np.asarray(lengths, dtype=np.float64)
    m = np.asarray(mirror, dtype=np.intp)
    if est.ndim != 1 or m.shape != est.shape:
        raise ValueError(f"lengths and mirror must both be (B,), got {est.shape} and {m.shape}")
    twin = est[m]
    with np.errstate(invalid="ignore"):
        return (est > TWIN_MAX_RATIO * twin) & (est - twin > TWIN_MAX_EXCESS_M) & (twin >= TWIN_MIN_M)


def seen_bone_lengths(positions: np.ndarray, seen: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """``(..., B)`` bone lengths (m) of ``positions`` ``(..., J, 3)`` where both ends are ``seen``
    ``(..., J)``, NaN elsewhere (one frame or many)."""
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    s = np.asarray(seen, dtype=bool)
    both = s[..., b[:, 0]] & s[..., b[:, 1]]
    return np.where(both, bone_lengths_per_frame(positions, b), np.nan)


def symmetric_lengths(
    lengths: np.ndarray, support: np.ndarray, mirror: np.ndarray, own_support: int = 30,
    pool: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A poorly seen bone borrows its length from its left/right counterpart.

    ``lengths`` ``(B,)`` m (NaN = unknown), ``support`` ``(B,)`` samples behind each,
    ``mirror`` ``(B,)`` index of each bone's left/right counterpart (itself for midline
    bones). A bone with at least ``own_support`` samples keeps its own length (real
    bodies and mocap skeletons are asymmetric by a centimetre or two: pooling always raised
    the AJE on CMU 131_01 at 5 %); one with fewer, whose counterpart has
    at least ``own_support`` and twice as many, takes the support-weighted mean of the pair. A sensor's limb that is mostly *inferred* has few
    trustworthy samples, and the well-seen side fixes it (a seated Kinect user's inferred
    shin otherwise kept a length from 8 frames, 0.53 m against the tracked side's
    0.385 m). ``pool`` ``(B,)`` bool or weight in [0, 1]: bones pooled with their
    counterpart whatever the support (both sides of the pair move that far toward the
    support-weighted mean of the two): bones of limbs the
    sensor has been guessing (*inferred*), whose own samples, however many, are the
    sensor's guesses; a person's left and right bones are the same length to within a few
    per cent, which the guessed side otherwise misses by 10-30 % (a seated Kinect user's
    inferred hands). Returns the lengths and their support (pooled where pooled).
    """
    l = np.asarray(lengths, dtype=np.float64)
    s = np.where(np.isfinite(l), np.asarray(support, dtype=np.float64), 0.0)
    m = np.asarray(mirror, dtype=np.intp)
    total = s + s[m]
    pooled = np.where(total > 0, (np.nan_to_num(l) * s + np.nan_to_num(l[m]) * s[m]) / np.maximum(total, 1e-12), np.nan)
    # borrow only from a counterpart that is itself well seen and clearly better seen:
    # early in a stream both sides are thin, and pooling them then only adds asymmetry error
    borrow = (m != np.arange(len(l))) & (s < own_support) & (s[m] >= own_support) & (s[m] >= 2 * s)
    out_l, out_s = np.where(borrow, pooled, l), np.where(borrow, total, s)
    if pool is not None:
        # a weight in [0, 1] per bone (True = 1): the pair moves that far toward its pooled
        # length, so a limb whose share of guessed samples grows does not switch lengths
        # (and jump) from one window to the next
        w = np.asarray(pool, dtype=np.float64)
        w = np.where((m != np.arange(len(l))) & (total > 0) & ~borrow, np.maximum(w, w[m]), 0.0)
        out_l = np.where(w > 0, (1.0 - w) * out_l + w * np.nan_to_num(pooled), out_l)
        out_s = np.where(w >= 1.0, total, out_s)
    return out_l, out_s


def estimate_bone_lengths(
    positions: np.ndarray,
    bones: np.ndarray,
    observed: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
    method: str = "mode",
    fraction: float = 0.1,
) -> np.ndarray:
    """Robust ``(B,)`` bone lengths (metres) from a possibly corrupted motion.

    Uses only frames where both ends are observed (and, when ``confidence`` is given,
    where both ends have the highest confidence available for that bone, e.g. tracked
    rather than inferred). ``method``:

    * ``'mode'`` (default): middle of the shortest length interval holding ``fraction``
      of those frames. Outliers add noise to *both* ends' coordinates, so at 20 % of
      corrupted coordinates ~74 % of frames have a corrupted bone and the median is
      biased (measured on CMU 131_01); the clean frames still form the densest
      cluster, which the mode finds almost exactly (measured there too).
    * ``'median'``: the per-bone median over frames (robust while < 50 % are corrupted).

    The window solver's own estimate, for a window with no lengths given. The engine's
    per-body lengths from a sensor's history use :func:`length_mode_with_support` (the
    densest mode), which weighs a cluster by its samples; here, under the paper protocol's
    corruption of most frames, the narrowest cluster is the clean one (the densest mode
    raised the 80 % rows of ``benchmarks/bench_accuracy.py``).

    A bone never observed gets NaN.
    """
    p = np.asarray(positions, dtype=np.float64)
    b = _bones(bones, p.shape[1])
    lengths = bone_lengths_per_frame(p, b)  # (T, B)
    ok = np.isfinite(lengths)
    if observed is not None:
        obs = np.asarray(observed, dtype=bool)
        if obs.shape != p.shape[:2]:
            raise ValueError(f"observed must be {p.shape[:2]}, got {obs.shape}")
        ok &= obs[:, b[:, 0]] & obs[:, b[:, 1]]
    if confidence is not None:
        conf = np.asarray(confidence, dtype=np.float64)
        if conf.shape != p.shape[:2]:
            raise ValueError(f"confidence must be {p.shape[:2]}, got {conf.shape}")
        c = np.minimum(conf[:, b[:, 0]], conf[:, b[:, 1]])
        c = np.where(ok, c, -np.inf)
        best = c.max(axis=0, keepdims=True)
        ok &= c >= best
    vals = np.where(ok, lengths, np.nan)
    if method == "mode":
        if not 0.0 < fraction <= 1.0:
            raise ValueError(f"fraction must be in (0, 1], got {fraction}")
        return _shorth_mode(vals, fraction)
    if method == "median":
        out = np.full(len(b), np.nan)
        seen = ok.any(axis=0)
        if seen.any():
            out[seen] = np.nanmedian(vals[:, seen], axis=0)
        return out
    raise ValueError(f"method must be 'mode' or 'median', got {method!r}")


def isometry_residual(positions: np.ndarray, bones: np.ndarray, bone_lengths: np.ndarray) -> np.ndarray:
    """F(N) of Eq. (16): ``(T, B)`` residuals r_th = d^2(n_i^t, n_j^t) - l_h^2 (m^2)."""
    u = bone_vectors(positions, bones)
    return np.einsum("tbc,tbc->tb", u, u) - np.asarray(bone_lengths, dtype=np.float64) ** 2


def isometry_jacobian(positions: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Dense per-frame Jacobian blocks ``(T, B, 3S)`` of F (Eq. 17), column = 3*joint + coord.

    Reference implementation (tests, small cases); the solver never forms it.
    """
    p = np.asarray(positions, dtype=np.float64)
    n_frames, n_joints, _ = p.shape
    b = _bones(bones, n_joints)
    u = bone_vectors(p, b)
    jac = np.zeros((n_frames, len(b), n_joints, 3))
    rows = np.arange(len(b))
    jac[:, rows, b[:, 0], :] = 2.0 * u
    jac[:, rows, b[:, 1], :] = -2.0 * u
    return jac.reshape(n_frames, len(b), 3 * n_joints)


@lru_cache(maxsize=32)
def _band_plan(bones_key: bytes, n_bones: int, n_joints: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, tuple[np.ndarray, ...]]:
    """Bone order that makes K = rho/gamma I + J J^T banded, for a fixed bone list.

    (J J^T)_bb' is non-zero only when bones b and b' share a joint; reverse
    Cuthill-McKee on that pattern gives bandwidths 4 (CMU, 30 bones), 6 (Kinect v2),
    8 (Azure Kinect). Returns (perm, bones in that order, their incidence matrix,
    bandwidth kb, the kb + 1 diagonals of M M^T in that order).
    """
    b = np.frombuffer(bones_key, dtype=np.intp).reshape(n_bones, 2)
    M = incidence_matrix(b, n_joints)
    MMt = M @ M.T
    perm = reverse_cuthill_mckee(csr_matrix(np.abs(MMt) > 0), symmetric_mode=True).astype(np.intp)
    Q = MMt[np.ix_(perm, perm)]
    rows, cols = np.nonzero(Q)
    kb = int(np.abs(rows - cols).max()) if len(rows) else 0
    diags = tuple(np.diagonal(Q, offset=d).copy() for d in range(kb + 1))
    Mp = M[perm]
    Mp.setflags(write=False)
    return perm, b[perm], Mp, kb, diags


@lru_cache(maxsize=32)
def _band_rows(bones_key: bytes, n_bones: int, n_joints: int) -> np.ndarray:
    """The diagonals of :func:`_band_plan` as one zero-padded ``(kb + 1, B)`` array
    (row d = the d-th diagonal of M M^T), the layout of the compiled step."""
    diags = _band_plan(bones_key, n_bones, n_joints)[4]
    rows = np.zeros((len(diags), n_bones))
    for d, diag in enumerate(diags):
        rows[d, : len(diag)] = diag
    return rows  # writeable: the compiled step is specialised for writeable arrays only


def gauss_newton_step(
    N: np.ndarray,
    A: np.ndarray,
    Z2: np.ndarray,
    rho2: float,
    gamma: float,
    bones: np.ndarray,
    bone_lengths: np.ndarray,
    incidence: np.ndarray | None = None,
) -> np.ndarray:
    """One Gauss-Newton update of the N-subproblem, Eq. (20); returns N + delta.

        delta = (gamma J^T J + rho2 I)^-1 (-Z2 - rho2 (N - A) - gamma J^T F)

    All of ``N, A, Z2`` are ``(T, S, 3)``. J^T J is block diagonal over frames
    (``3S x 3S`` blocks); per frame the inverse is applied by the Woodbury identity
    with the ``B x B`` matrix K = rho2/gamma I + J J^T:
        (gamma J^T J + rho2 I)^-1 g = (g - J^T K^-1 J g) / rho2,
    where (J J^T)_bb' = 4 (M M^T)_bb' (u_b . u_b') with M the bone incidence matrix.
    In a bandwidth-reducing bone order K is banded, so all T systems are solved as one
    block-diagonal banded SPD system (LAPACK ``pbsv``, a single call, no loop over
    frames). Bones with a NaN length are ignored. ``incidence`` is accepted for
    backward compatibility and unused.
    """
    n_frames, n_joints, _ = N.shape
    b = _bones(bones, n_joints)
    lengths = np.asarray(bone_lengths, dtype=np.float64)
    keep = np.isfinite(lengths)
    if not keep.all():
        b, lengths = b[keep], lengths[keep]
    if len(b) == 0 or gamma == 0:
        return A - Z2 / rho2  # minimiser of <Z2, N - A> + rho2/2 ||N - A||^2
    key = np.ascontiguousarray(b).tobytes()
    perm, bp, Mp, kb, diags = _band_plan(key, len(b), n_joints)
    lengths = lengths[perm]
    if kernels.COMPILED:  # the same update, compiled (one banded Cholesky per frame)
        out = kernels.gauss_newton_update(N, A, Z2, rho2, gamma, bp, lengths, _band_rows(key, len(b), n_joints))
        if out is not None:
            return out
    n_bones = len(bp)
    i, j = bp[:, 0], bp[:, 1]
    u = N[:, i, :] - N[:, j, :]                                   # (T, B, 3) bone vectors
    F = np.einsum("tbc,tbc->tb", u, u) - lengths**2               # Eq. (16), (T, B)

    def jt(y: np.ndarray) -> np.ndarray:
        """J^T y for per-bone weights y (T, B): 2 u y added to the parent, subtracted from the child."""
        v = 2.0 * u * y[..., None]                                # (T, B, 3)
        return np.tensordot(v, Mp, axes=([1], [0])).transpose(0, 2, 1)  # (T, S, 3)

    # g = -Z2 - rho2 (N - A) - gamma J^T F            (right-hand side of Eq. 20)
    g = -Z2 - rho2 * (N - A) - gamma * jt(F)
    # J g: (J g)_tb = 2 u_tb . (g_i - g_j)
    jg = 2.0 * np.einsum("tbc,tbc->tb", u, g[:, i, :] - g[:, j, :])
    # K_t in banded upper storage: ab[kb - d, t*B + k] = K_t[k - d, k]
    ab = np.zeros((kb + 1, n_frames, n_bones))
    for d in range(kb + 1):  # the kb + 1 (<= ~8) diagonals, each vectorised over frames
        ab[kb - d, :, d:] = 4.0 * diags[d] * np.einsum("tkc,tkc->tk", u[:, : n_bones - d], u[:, d:])
    ab[kb] += rho2 / gamma
    _, y, info = _pbsv(ab.reshape(kb + 1, -1), jg.reshape(-1), lower=0, overwrite_ab=1, overwrite_b=1)
    if info != 0:  # not expected (K is SPD); fall back to per-frame dense solves
        K = 4.0 * (Mp @ Mp.T)[None] * np.matmul(u, u.transpose(0, 2, 1))
        K[:, np.arange(n_bones), np.arange(n_bones)] += rho2 / gamma
        y = np.linalg.solve(K, jg[..., None])[..., 0]
    delta = (g - jt(y.reshape(n_frames, n_bones))) / rho2         # Woodbury
    return N + delta


def bone_length_deviations(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray,
                           min_bone_m: float) -> np.ndarray:
    """Per bone ``(B,)``: median over frames of ``|l_t - median_t l|`` (m), how far a bone's
    length strays from its typical length, on the frames where both ends are ``observed``
    ``(T, J)``. NaN for a bone never seen or whose typical length is not above ``min_bone_m``
    (BVH hierarchies contain zero-length bones). Compiled when numba is there
    (:func:`streamfix.core.kernels.bone_spread_deviations`); this numpy code is its reference."""
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if len(b) == 0:
        return np.zeros(0)
    if kernels.COMPILED:
        return kernels.bone_spread_deviations(positions, observed, b, min_bone_m)
    lengths = np.where(observed[:, b[:, 0]] & observed[:, b[:, 1]], bone_lengths_per_frame(positions, b), np.nan)
    typical = nanmedian(lengths, axis=0)
    dev = nanmedian(np.abs(lengths - typical), axis=0)
    return np.where(typical > min_bone_m, dev, np.nan)
