"""Compiled hot loops of the window cleaner (numba), each the same math as a numpy reference.

Why: a window solve is thousands of small numpy calls (a weighted local quadratic is
eight ``correlate1d`` passes and a dozen elementwise ops, run 20+ times per window), so
call overhead, not arithmetic, sets its cost. Each kernel here fuses one such stage
into a single compiled loop over frames and channels:

* :func:`local_poly`: the weighted local quadratic of
  :func:`streamfix.core.local_poly.local_poly_numpy` (tricube kernel, closed-form LDL^T, LU
  with partial pivoting where elimination cancelled a pivot);
* :func:`robust_temporal_fit`: stage 1 of the window cleaner (median start, Tukey
  reweighting, local quadratics) with no numpy temporaries between its passes;
* :func:`running_median`: the centred running median of
  :func:`streamfix.core.filters.running_median` (a sorted window updated frame by
  frame instead of one sort per frame; bit for bit the same values), and
  :func:`detrended_edges`, its edge frames moved along the edges' robust slopes;
* :func:`project_bone_lengths_pbd`: the Jacobi constraint iterations of
  :func:`streamfix.core.bone_projection.project_bone_lengths_pbd`, frame by frame;
* :func:`bone_spread_deviations`: the window cleaner's rigidity score per bone (bone
  lengths and both medians over a window in one pass), bit for bit;
* :func:`gauss_newton_update`: the isometry step of
  :func:`streamfix.core.isometry.gauss_newton_step`, a banded Cholesky per frame
  instead of one LAPACK call on a block-diagonal band (same systems, rounding apart);
* :func:`shorth_mode`: the robust bone-length mode of
  :func:`streamfix.core.isometry._shorth_mode`, bit for bit, and
  :func:`length_mode_with_support`, the densest mode refined and its support counted
  (:func:`streamfix.core.isometry.length_mode_with_support`) from the same sort;
* :func:`theil_sen_line`: the live path's robust line through the last raw samples
  (:meth:`streamfix.streaming.live.LivePath.robust_line`), bit for bit;
* :func:`kabsch_rotations`: the best rotations of :func:`streamfix.core.pca_normalise.kabsch_svd`
  (PCA gap filling normalises every frame with one), without a batched 3x3 SVD;
* :func:`live_step`: one whole frame of the live path's default chain (that gate with its
  rigid release, the One Euro filter, the bone projection) in one call, bit for bit: the
  per-frame path is dozens of tiny numpy calls per body, and their overhead was most of its cost;
* :func:`live_carry`: the windows' verdict carried onto one live frame
  (:meth:`streamfix.streaming.live_carry.WindowCarry.apply`), bit for bit: a dozen small numpy
  calls per frame whenever a joint is carried, which is whenever the sensor has lost one;
* :func:`live_pose_bias`: the learned sensor bias removed from one frame
  (:func:`streamfix.core.pose_bias.remove_pose_bias` on one frame, rounding apart): the
  numpy batch function was slow there.

The numpy functions stay the reference: tests compare each kernel with them on real
recordings (``tests/test_core_kernels.py``). Callers check :data:`COMPILED` at each
call: False without numba (an environment that cannot install it) or with
``STREAMFIX_NUMBA=0`` in the environment, and then the numpy references run; nothing
else changes. Kernels release the GIL (``nogil``) so a solver thread does not stall
the live path. Compiled code is cached on disk next to this module (first import
compiles, later processes load it).

Arrays: positions in metres, time along axis 0 (frames).
"""
from __future__ import annotations

import functools
import os

import numpy as np

__all__ = [
    "COMPILED", "HAVE_NUMBA", "local_poly", "running_median", "detrended_edges", "DETRENDED_EDGES_MAX_WINDOW",
    "pbd_constraints", "project_bone_lengths_pbd",
    "gauss_newton_update", "robust_temporal_fit", "theil_sen_line", "bone_spread_deviations",
    "shorth_mode", "length_mode_with_support", "live_step", "kabsch_rotations", "warm_up",
    "live_pose_bias", "live_carry", "pair_distances",
]

try:  # optional at runtime: the numpy references are used without it
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only where numba is absent
    _numba = None

HAVE_NUMBA = _numba is not None
"""numba could be imported."""

COMPILED = HAVE_NUMBA and os.environ.get("STREAMFIX_NUMBA", "1") != "0"
"""Callers use the compiled kernels (numba present and ``STREAMFIX_NUMBA`` is not ``0``);
False: the numpy references. Read at each call, so it may be switched at runtime
(tests and ``benchmarks/bench_speed.py --reference`` time both in one process)."""

_PIVOT_RTOL = 1e-4  # the same threshold as streamfix.core.local_poly.local_poly_numpy


def _jit(fn, error_model: str = "python"):
    """Compile ``fn`` with numba (no Python objects, GIL released, cached on disk), or None.

    ``error_model='numpy'``: a float division by zero gives inf/NaN as in numpy instead of
    raising, which lets the compiler vectorise divisions (the same IEEE results otherwise)."""
    if _numba is None:
        return None
    try:
        return _numba.njit(cache=True, nogil=True, fastmath=False, error_model=error_model)(fn)
    except RuntimeError:  # no writable cache location at all: compile in each process
        return _numba.njit(nogil=True, fastmath=False, error_model=error_model)(fn)


# --------------------------------------------------------------------------- local quadratic
def _local_poly_loop(y, w, taps, fit, support, pivot_rtol):  # pragma: no cover - compiled
    n_frames, n_ch = y.shape
    n_taps = taps.shape[1]
    h = (n_taps - 1) // 2
    s0 = np.empty(n_ch)
    s1 = np.empty(n_ch)
    s2 = np.empty(n_ch)
    s3 = np.empty(n_ch)
    s4 = np.empty(n_ch)
    r0 = np.empty(n_ch)
    r1 = np.empty(n_ch)
    r2 = np.empty(n_ch)
    row = np.empty(n_ch)
    gap1 = np.empty(n_ch)
    gap2 = np.empty(n_ch)
    # zero-padded weights and weighted values: no bounds tests in the inner loop
    wp = np.zeros((n_frames + 2 * h, n_ch))
    yp = np.zeros((n_frames + 2 * h, n_ch))
    for t in range(n_frames):
        for c in range(n_ch):
            wp[t + h, c] = w[t, c]
            yp[t + h, c] = w[t, c] * y[t, c]
    for t in range(n_frames):
        # centre tap, then the pairs t - j, t + j: even moments of the kernel are symmetric
        # and odd ones antisymmetric, so each pair costs one multiply per moment
        tc = t + h
        for c in range(n_ch):
            wc = wp[tc, c]
            wy = yp[tc, c]
            s0[c] = taps[0, h] * wc
            s1[c] = taps[1, h] * wc
            s2[c] = taps[2, h] * wc
            s3[c] = taps[3, h] * wc
            s4[c] = taps[4, h] * wc
            r0[c] = taps[0, h] * wy
            r1[c] = taps[1, h] * wy
            r2[c] = taps[2, h] * wy
        # two pairs per pass over the channels (j, j + 1), added in the same order as one
        # at a time: the same sums, half the loads and stores of the accumulators
        for j in range(1, h, 2):
            lo = tc - j
            hi = tc + j
            a0 = taps[0, h + j]
            a1 = taps[1, h + j]
            a2 = taps[2, h + j]
            a3 = taps[3, h + j]
            a4 = taps[4, h + j]
            b0 = taps[0, h + j + 1]
            b1 = taps[1, h + j + 1]
            b2 = taps[2, h + j + 1]
            b3 = taps[3, h + j + 1]
            b4 = taps[4, h + j + 1]
            for c in range(n_ch):
                ws = wp[hi, c] + wp[lo, c]
                wd = wp[hi, c] - wp[lo, c]
                ys = yp[hi, c] + yp[lo, c]
                yd = yp[hi, c] - yp[lo, c]
                vs = wp[hi + 1, c] + wp[lo - 1, c]
                vd = wp[hi + 1, c] - wp[lo - 1, c]
                xs = yp[hi + 1, c] + yp[lo - 1, c]
                xd = yp[hi + 1, c] - yp[lo - 1, c]
                s0[c] = (s0[c] + a0 * ws) + b0 * vs
                s1[c] = (s1[c] + a1 * wd) + b1 * vd
                s2[c] = (s2[c] + a2 * ws) + b2 * vs
                s3[c] = (s3[c] + a3 * wd) + b3 * vd
                s4[c] = (s4[c] + a4 * ws) + b4 * vs
                r0[c] = (r0[c] + a0 * ys) + b0 * xs
                r1[c] = (r1[c] + a1 * yd) + b1 * xd
                r2[c] = (r2[c] + a2 * ys) + b2 * xs
        if h % 2 == 1:  # the last pair, j = h, alone
            lo = tc - h
            hi = tc + h
            a0 = taps[0, 2 * h]
            a1 = taps[1, 2 * h]
            a2 = taps[2, 2 * h]
            a3 = taps[3, 2 * h]
            a4 = taps[4, 2 * h]
            for c in range(n_ch):
                ws = wp[hi, c] + wp[lo, c]
                wd = wp[hi, c] - wp[lo, c]
                ys = yp[hi, c] + yp[lo, c]
                yd = yp[hi, c] - yp[lo, c]
                s0[c] += a0 * ws
                s1[c] += a1 * wd
                s2[c] += a2 * ws
                s3[c] += a3 * wd
                s4[c] += a4 * ws
                r0[c] += a0 * ys
                r1[c] += a1 * yd
                r2[c] += a2 * ys
        # the LDL^T solve, branch-free so the divisions vectorise; channels whose
        # elimination cancelled a pivot are solved again by LU with pivoting below
        for c in range(n_ch):
            m00 = s0[c] + 1e-12
            m11 = s2[c] + 1e-9
            m22 = s4[c] + 1e-9
            l10 = s1[c] / m00
            l20 = s2[c] / m00
            d1 = m11 - l10 * s1[c]
            l21 = (s3[c] - l20 * s1[c]) / d1
            d2 = m22 - l20 * s2[c] - l21 * l21 * d1
            z1 = r1[c] - l10 * r0[c]
            a2s = (r2[c] - l20 * r0[c] - l21 * z1) / d2
            a1s = z1 / d1 - l21 * a2s
            row[c] = r0[c] / m00 - l10 * a1s - l20 * a2s
            gap1[c] = d1 - pivot_rtol * m11
            gap2[c] = d2 - pivot_rtol * m22
        for c in range(n_ch):
            if gap1[c] < 0.0 or gap2[c] < 0.0:  # a pivot below its share (NaN: left as it is)
                row[c] = _solve3_first(s0[c] + 1e-12, s1[c], s2[c], s2[c] + 1e-9, s3[c], s4[c] + 1e-9,
                                       r0[c], r1[c], r2[c])
            fit[t, c] = row[c]
            support[t, c] = s0[c]


def _solve3_first_py(m00, m01, m02, m11, m12, m22, b0, b1, b2):  # pragma: no cover - compiled
    """First unknown of the symmetric 3x3 system by LU with partial pivoting (as LAPACK gesv).

    Rows held in scalars (no array allocated per call: the robust fit's sparse windows
    take this path for many frames); the same operations in the same order as the
    textbook loop (first row of largest magnitude as pivot, elimination by the
    reciprocal pivot, back substitution column by column), so the same bits."""
    a00, a01, a02, c0 = m00, m01, m02, b0
    a10, a11, a12, c1 = m01, m11, m12, b1
    a20, a21, a22, c2 = m02, m12, m22, b2
    # column 0: the pivot row moves up (rows swap whole)
    if abs(a10) > abs(a00):
        if abs(a20) > abs(a10):
            a00, a01, a02, c0, a20, a21, a22, c2 = a20, a21, a22, c2, a00, a01, a02, c0
        else:
            a00, a01, a02, c0, a10, a11, a12, c1 = a10, a11, a12, c1, a00, a01, a02, c0
    elif abs(a20) > abs(a00):
        a00, a01, a02, c0, a20, a21, a22, c2 = a20, a21, a22, c2, a00, a01, a02, c0
    inv = 1.0 / a00  # LAPACK's getf2 scales the column by the reciprocal pivot
    f = a10 * inv
    a11 -= f * a01
    a12 -= f * a02
    c1 -= f * c0
    f = a20 * inv
    a21 -= f * a01
    a22 -= f * a02
    c2 -= f * c0
    # column 1
    if abs(a21) > abs(a11):
        a11, a12, c1, a21, a22, c2 = a21, a22, c2, a11, a12, c1
    f = a21 * (1.0 / a11)
    a22 -= f * a12
    c2 -= f * c1
    # back substitution column by column, as LAPACK's trsm
    x2 = c2 / a22
    c1 = c1 - x2 * a12
    c0 = c0 - x2 * a02
    x1 = c1 / a11
    c0 -= x1 * a01
    return c0 / a00


@functools.lru_cache(maxsize=64)
def _poly_taps(h: int) -> np.ndarray:
    """``(5, 2h + 1)`` moments ``K(k) (k/h)^m`` of the tricube kernel of half-width ``h`` frames
    (the coefficients of :func:`streamfix.core.local_poly.local_poly_numpy`); cached, read-only."""
    k = np.arange(-h, h + 1, dtype=np.float64)
    K = (1.0 - (np.abs(k) / (h + 1)) ** 3) ** 3
    u = k / h
    taps = np.stack([K * u**m for m in range(5)])
    taps.setflags(write=False)
    return taps


_solve3_first = _jit(_solve3_first_py)
_local_poly_compiled = _jit(_local_poly_loop, error_model="numpy")  # vectorised divisions


def local_poly(y: np.ndarray, w: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Weighted local quadratic fit of ``y`` ``(T, C)`` with weights ``w``, half-width ``h`` frames.

    The same normal equations and solve as :func:`streamfix.core.local_poly.local_poly_numpy`
    (tricube kernel, abscissa scaled by ``h``), summed in one compiled pass over the
    window instead of eight correlations. Returns ``(fit, support)``, support = the
    kernel-weighted sum of ``w``. Needs numba (:data:`HAVE_NUMBA`).
    """
    if _local_poly_compiled is None:
        raise RuntimeError("streamfix.core.kernels.local_poly needs numba; use streamfix.core.local_poly.local_poly_numpy")
    taps = _poly_taps(int(h))  # the same coefficients as the reference
    y = np.ascontiguousarray(y, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    fit = np.empty_like(y)
    support = np.empty_like(y)
    _local_poly_compiled(y, w, taps, fit, support, _PIVOT_RTOL)
    return fit, support


# --------------------------------------------------------------------------- running median
def _running_median_loop(x, window, out):  # pragma: no cover - compiled
    """Running median of ``x`` ``(T, C)`` into ``out``: one sorted window per channel, updated by
    insertion and deletion (shrunken windows at the edges, NaN = missing)."""
    n_frames, n_ch = x.shape
    half = window // 2
    ahead = window - 1 - half  # frames after t in t's window (half for odd windows)
    buf = np.empty(window)
    for c in range(n_ch):
        n = 0  # finite samples in the window, sorted ascending in buf[:n]
        for t in range(-ahead, n_frames):
            enter = t + ahead
            if enter < n_frames:
                v = x[enter, c]
                if v == v:  # not NaN
                    pos = n
                    while pos > 0 and buf[pos - 1] > v:
                        buf[pos] = buf[pos - 1]
                        pos -= 1
                    buf[pos] = v
                    n += 1
            if t < 0:
                continue
            if n == 0:
                out[t, c] = np.nan
            else:
                out[t, c] = (buf[(n - 1) // 2] + buf[n // 2]) / 2.0
            leave = t - half
            if leave >= 0:
                v = x[leave, c]
                if v == v:
                    pos = 0
                    while buf[pos] != v:
                        pos += 1
                    for q in range(pos, n - 1):
                        buf[q] = buf[q + 1]
                    n -= 1


_running_median_sorted_compiled = _jit(_running_median_loop)


def _running_median_wide_loop(x, window, out):  # pragma: no cover - compiled
    """:func:`_running_median_loop`'s values, all channels advanced together: each channel's
    window is kept sorted in ``sorted_[:, c]``, ``window`` slots, empty ones (and missing
    samples) held as +inf. One step removes the frame that left and inserts the one that
    entered with comparisons and min/max only: the slot q after removing a is
    ``s[q + 1] if s[q] >= a else s[q]`` (r), after inserting b ``min(max(r[q - 1], b), r[q])``.
    Why: the insertion sort's data-dependent loops mispredict most of their time away; these
    branch-free steps run along contiguous channels, which the compiler vectorises (faster on
    the window cleaner's 75 channels; slower than the sorted loop below ~16 channels). A real
    +inf sample is indistinguishable from an empty slot, which gives the same medians."""
    n_frames, n_ch = x.shape
    half = window // 2
    ahead = window - 1 - half
    sorted_ = np.full((window, n_ch), np.inf)
    below = np.empty(n_ch)  # r[q - 1] of the step in progress
    leaving = np.empty(n_ch)
    entering = np.empty(n_ch)
    count = np.zeros(n_ch, dtype=np.int64)  # samples (not NaN) in each channel's window
    for t in range(-ahead, n_frames):
        leave = t - half - 1
        enter = t + ahead
        for c in range(n_ch):
            leaving[c] = np.inf
            entering[c] = np.inf
        if leave >= 0:
            for c in range(n_ch):
                v = x[leave, c]
                present = v == v
                leaving[c] = v if present else np.inf
                count[c] -= present
        if enter < n_frames:
            for c in range(n_ch):
                v = x[enter, c]
                present = v == v
                entering[c] = v if present else np.inf
                count[c] += present
        for c in range(n_ch):
            below[c] = -np.inf
        for q in range(window - 1):
            for c in range(n_ch):
                s = sorted_[q, c]
                r = sorted_[q + 1, c] if s >= leaving[c] else s
                m = below[c] if below[c] > entering[c] else entering[c]
                sorted_[q, c] = m if m < r else r
                below[c] = r
        for c in range(n_ch):
            sorted_[window - 1, c] = below[c] if below[c] > entering[c] else entering[c]
        if t >= 0:
            for c in range(n_ch):
                n = count[c]
                if n == 0:
                    out[t, c] = np.nan
                else:
                    out[t, c] = (sorted_[(n - 1) // 2, c] + sorted_[n // 2, c]) / 2.0


_running_median_wide_compiled = _jit(_running_median_wide_loop, error_model="numpy")
_WIDE_MEDIAN_MIN_CHANNELS = 16  # measured: the branch-free steps win from about here


def _running_median_any(x, window, out):  # pragma: no cover - compiled
    """The running median of ``x`` ``(T, C)`` by whichever loop is faster for C channels."""
    if x.shape[1] >= _WIDE_MEDIAN_MIN_CHANNELS:
        _running_median_wide_compiled(x, window, out)
    else:
        _running_median_sorted_compiled(x, window, out)


_running_median_compiled = _jit(_running_median_any)


def running_median(x: np.ndarray, window: int) -> np.ndarray:
    """Centred running median over ``window`` frames of ``x`` ``(T, ...)``, NaN = missing.

    Shrunken windows at the edges, NaN only where a whole window is missing: the same
    values as :func:`streamfix.core.filters.running_median` bit for bit (the middle
    sample, or the mean of the two middle ones). Needs numba (:data:`HAVE_NUMBA`).
    """
    if _running_median_compiled is None:
        raise RuntimeError("streamfix.core.kernels.running_median needs numba; use streamfix.core.filters.running_median")
    x = np.asarray(x, dtype=np.float64)
    flat = np.ascontiguousarray(x.reshape(x.shape[0], -1))
    out = np.empty_like(flat)
    if flat.size:
        _running_median_compiled(flat, int(window), out)
    return out.reshape(x.shape)


# --------------------------------------------------------------------------- bone projection
def _pbd_loop(xt, bi, bj, target, wi, wj, iterations):  # pragma: no cover - compiled
    """Jacobi iterations on ``xt`` ``(J, 3, T)`` in place; ``target`` ``(B, T)``: each bone's
    length per frame; ``wi``/``wj`` ``(B, T)``: each bone's share of its length error at its
    parent/child end, over that joint's bone count. Frames are independent, so the innermost
    loop runs over them (contiguous: it vectorises)."""
    n_joints, _, n_frames = xt.shape
    n_bones = bi.shape[0]
    delta = np.empty((n_joints, 3, n_frames))
    for _ in range(iterations):
        delta[:, :, :] = 0.0
        for b in range(n_bones):
            i = bi[b]
            j = bj[b]
            for t in range(n_frames):
                u0 = xt[i, 0, t] - xt[j, 0, t]
                u1 = xt[i, 1, t] - xt[j, 1, t]
                u2 = xt[i, 2, t] - xt[j, 2, t]
                norm = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
                err = (norm - target[b, t]) / norm if norm > 1e-9 else 0.0
                a = wi[b, t] * err
                d = wj[b, t] * err
                delta[i, 0, t] -= u0 * a
                delta[i, 1, t] -= u1 * a
                delta[i, 2, t] -= u2 * a
                delta[j, 0, t] += u0 * d
                delta[j, 1, t] += u1 * d
                delta[j, 2, t] += u2 * d
        for q in range(n_joints):
            for c in range(3):
                for t in range(n_frames):
                    xt[q, c, t] += delta[q, c, t]


_pbd_compiled = _jit(_pbd_loop, error_model="numpy")  # vectorised divisions


def pbd_constraints(
    shape: tuple[int, ...], bones: np.ndarray, bone_lengths: np.ndarray, inverse_mass: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The bone constraints of a Jacobi bone-length projection on positions of ``shape``
    ``(T, J, 3)``, shared by the numpy reference and the compiled loop.

    ``bone_lengths``: ``(B,)``, or ``(T, B)`` for a length per frame (m). Returns
    ``(i, j, targets, share_i, degree)``: the bones with a finite length in every frame
    (parent ``i``, child ``j``, contiguous), their length in each frame ``(B, T)``, each
    bone's share of its length error taken by ``i`` ``(T, B)`` (its inverse mass over the
    pair's; 0.5 when both are 0) and each joint's number of bones ``(J,)``.
    """
    n_frames, n_joints = shape[0], shape[1]
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    lengths = np.asarray(bone_lengths, dtype=np.float64)
    per_frame = lengths if lengths.ndim == 2 else np.broadcast_to(lengths, (n_frames, len(lengths)))
    keep = np.isfinite(per_frame).all(axis=0)
    b = b[keep]
    targets = np.ascontiguousarray(per_frame[:, keep].T)
    im = np.ones((n_frames, n_joints)) if inverse_mass is None else np.asarray(inverse_mass, dtype=np.float64)
    i, j = np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1])
    wi, wj = im[:, i], im[:, j]
    share_i = np.ascontiguousarray(np.where(wi + wj > 0, wi / np.maximum(wi + wj, 1e-12), 0.5))
    degree = np.bincount(np.concatenate([i, j]), minlength=n_joints).astype(np.float64)
    return i, j, targets, share_i, degree


def project_bone_lengths_pbd(
    positions: np.ndarray,
    bones: np.ndarray,
    bone_lengths: np.ndarray,
    iterations: int = 20,
    inverse_mass: np.ndarray | None = None,
) -> np.ndarray:
    """Jacobi bone-length iterations, compiled: the math of
    :func:`streamfix.core.bone_projection.project_bone_lengths_pbd` (same arguments, same result
    up to summation order), one frame at a time. Needs numba (:data:`HAVE_NUMBA`)."""
    if _pbd_compiled is None:
        raise RuntimeError("streamfix.core.kernels.project_bone_lengths_pbd needs numba; use streamfix.core.pipeline's")
    x = np.array(positions, dtype=np.float64, order="C", copy=True)
    i, j, targets, share_i, degree = pbd_constraints(x.shape, bones, bone_lengths, inverse_mass)
    if len(i) == 0 or iterations <= 0 or not np.isfinite(x).all():
        return x
    inv_degree = 1.0 / np.maximum(degree, 1.0)
    wi = np.ascontiguousarray((share_i * inv_degree[i]).T)          # (B, T)
    wj = np.ascontiguousarray(((1.0 - share_i) * inv_degree[j]).T)
    xt = np.ascontiguousarray(x.transpose(1, 2, 0))                  # (J, 3, T): frames innermost
    _pbd_compiled(xt, i, j, targets, wi, wj, int(iterations))
    return np.ascontiguousarray(xt.transpose(2, 0, 1))


# --------------------------------------------------------------------------- pose bias, one frame
def _unit_into(v, out):  # pragma: no cover - compiled
    norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    for c in range(3):
        out[c] = v[c] / norm


def _pose_bias_frame_loop(pos, frame_idx, seg_p, seg_c, group_start, sensor_direction, sensor_weight, min_distance,
                          feature_mean, weights, centres, fade_start, fade_end, max_correction, follow,
                          out):  # pragma: no cover - compiled
    """The correction of one frame into ``out`` (J, 3); returns False (``out`` zero) where a
    feature is not finite."""
    n_joints = pos.shape[0]
    for j in range(n_joints):
        for c in range(3):
            out[j, c] = 0.0
    ls, rs, pelvis, neck = frame_idx[0], frame_idx[1], frame_idx[2], frame_idx[3]
    R = np.empty((3, 3))
    v = np.empty(3)
    u = np.empty(3)
    for c in range(3):
        v[c] = pos[rs, c] - pos[ls, c]
    _unit_into_compiled(v, u)
    for c in range(3):
        R[0, c] = u[c]
    up = np.empty(3)
    for c in range(3):
        up[c] = pos[neck, c] - pos[pelvis, c]
    dot = up[0] * R[0, 0] + up[1] * R[0, 1] + up[2] * R[0, 2]
    for c in range(3):
        v[c] = up[c] - dot * R[0, c]
    _unit_into_compiled(v, u)
    for c in range(3):
        R[1, c] = u[c]
    R[2, 0] = R[0, 1] * R[1, 2] - R[0, 2] * R[1, 1]
    R[2, 1] = R[0, 2] * R[1, 0] - R[0, 0] * R[1, 2]
    R[2, 2] = R[0, 0] * R[1, 1] - R[0, 1] * R[1, 0]
    sensor = np.empty(3)
    if sensor_direction:
        for c in range(3):
            v[c] = -0.5 * (pos[pelvis, c] + pos[neck, c])
        dist = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        for c in range(3):
            u[c] = v[c] / dist if dist >= min_distance else np.nan
        for i in range(3):
            sensor[i] = R[i, 0] * u[0] + R[i, 1] * u[1] + R[i, 2] * u[2]
    n_feat = feature_mean.shape[0]
    full = np.empty(n_feat)
    linear = np.empty(centres.shape[1])
    n_groups = group_start.shape[0] - 1
    fg = np.empty(3 * seg_p.shape[0] + 3)
    nf = 0
    nl = 0
    for g in range(n_groups):
        m = 0
        for s in range(group_start[g], group_start[g + 1]):
            for c in range(3):
                v[c] = pos[seg_c[s], c] - pos[seg_p[s], c]
            _unit_into_compiled(v, u)
            for i in range(3):
                fg[m] = R[i, 0] * u[0] + R[i, 1] * u[1] + R[i, 2] * u[2]
                linear[nl] = fg[m]
                m += 1
                nl += 1
        if sensor_direction:
            for i in range(3):
                fg[m] = sensor[i]
                m += 1
        for i in range(m):
            full[nf] = fg[i]
            nf += 1
        for i in range(m):
            for k in range(i, m):
                full[nf] = fg[i] * fg[k]
                nf += 1
    if sensor_direction:
        for i in range(3):
            linear[nl] = sensor_weight * sensor[i]
            nl += 1
    for f in range(n_feat):
        if not np.isfinite(full[f]):
            return False
    for i in range(3):
        for c in range(3):
            if not np.isfinite(R[i, c]):
                return False
    n_out = weights.shape[1]
    e = np.zeros(n_out)
    for f in range(n_feat):
        x = full[f] - feature_mean[f]
        for o in range(n_out):
            e[o] += x * weights[f, o]
    ll = 0.0
    for i in range(nl):
        ll += linear[i] * linear[i]
    best = np.inf
    for q in range(centres.shape[0]):
        lc = 0.0
        cc = 0.0
        for i in range(nl):
            lc += linear[i] * centres[q, i]
            cc += centres[q, i] * centres[q, i]
        d2 = ll - 2.0 * lc + cc
        if d2 < best:
            best = d2
    distance = np.sqrt(max(best, 0.0))
    fade = (fade_end - distance) / max(fade_end - fade_start, 1e-12)
    fade = min(max(fade, 0.0), 1.0)
    n_corrected = n_out // 3
    world = np.empty((n_corrected, 3))
    for k in range(n_corrected):
        norm = np.sqrt(e[3 * k] ** 2 + e[3 * k + 1] ** 2 + e[3 * k + 2] ** 2)
        scale = fade * min(1.0, max_correction[k] / max(norm, 1e-12))
        for c in range(3):
            world[k, c] = R[0, c] * e[3 * k] * scale + R[1, c] * e[3 * k + 1] * scale + R[2, c] * e[3 * k + 2] * scale
    for j in range(n_joints):
        for k in range(n_corrected):
            w = follow[j, k]
            if w != 0.0:
                for c in range(3):
                    out[j, c] += w * world[k, c]
    return True


# numpy's error model: a zero-length vector gives NaN (the frame is not corrected), as numpy does
_unit_into_compiled = _jit(_unit_into, error_model="numpy")
_pose_bias_frame_compiled = _jit(_pose_bias_frame_loop, error_model="numpy")


def _live_pose_bias_loop(pos, frame_idx, seg_p, seg_c, group_start, sensor_direction, sensor_weight, min_distance,
                         feature_mean, weights, centres, fade_start, fade_end, max_correction, follow,
                         bi, bj, wi, wj, iterations, alpha, previous, has_previous, out, shift):  # pragma: no cover
    n_joints = pos.shape[0]
    correction = np.empty((n_joints, 3))
    _pose_bias_frame_compiled(pos, frame_idx, seg_p, seg_c, group_start, sensor_direction, sensor_weight, min_distance,
                              feature_mean, weights, centres, fade_start, fade_end, max_correction, follow, correction)
    whole = True
    xt = np.empty((n_joints, 3, 1))
    for j in range(n_joints):
        for c in range(3):
            if not np.isfinite(pos[j, c]):
                whole = False
            xt[j, c, 0] = pos[j, c] - correction[j, c]
    n_bones = bi.shape[0]
    if whole and n_bones > 0 and iterations > 0:
        target = np.empty((n_bones, 1))
        for b in range(n_bones):
            d0 = pos[bj[b], 0] - pos[bi[b], 0]
            d1 = pos[bj[b], 1] - pos[bi[b], 1]
            d2 = pos[bj[b], 2] - pos[bi[b], 2]
            target[b, 0] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        _pbd_compiled(xt, bi, bj, target, wi, wj, iterations)
    for j in range(n_joints):
        for c in range(3):
            raw = xt[j, c, 0] - pos[j, c]
            if not np.isfinite(raw):
                raw = 0.0
            s = alpha * raw + (1.0 - alpha) * previous[j, c] if has_previous and alpha != 1.0 else raw
            shift[j, c] = s
            out[j, c] = pos[j, c] + s


_live_pose_bias_compiled = _jit(_live_pose_bias_loop, error_model="numpy")


def live_pose_bias(pos: np.ndarray, prepared: tuple, previous: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """One frame ``pos`` ``(J, 3)`` m less the learned sensor bias, put back on its own bone
    lengths and the shift smoothed from ``previous`` (None: unsmoothed): the math of
    :func:`streamfix.core.pose_bias.remove_pose_bias` on one frame (same result up to
    summation order) in one compiled call. ``prepared``: the model's and the projection's
    arrays (:class:`streamfix.core.pose_bias_live.LivePoseBias`). Returns ``(corrected, shift)``.
    Needs numba (:data:`HAVE_NUMBA`)."""
    if _live_pose_bias_compiled is None:
        raise RuntimeError("streamfix.core.kernels.live_pose_bias needs numba; use streamfix.core.pose_bias.remove_pose_bias")
    out = np.empty((pos.shape[0], 3))
    shift = np.empty((pos.shape[0], 3))
    has_previous = previous is not None
    prev = np.ascontiguousarray(previous, dtype=np.float64) if has_previous else out
    _live_pose_bias_compiled(np.ascontiguousarray(pos, dtype=np.float64), *prepared, prev, has_previous, out, shift)
    return out, shift

# --------------------------------------------------------------------------- Gauss-Newton step
def _gauss_newton_loop(N, A, Z2, rho2, gamma, bi, bj, sq_lengths, diags, out):  # pragma: no cover - compiled
    n_frames, n_joints, _ = N.shape
    n_bones = bi.shape[0]
    kb = diags.shape[0] - 1
    u = np.empty((n_bones, 3))
    g = np.empty((n_joints, 3))
    U = np.zeros((n_bones, n_bones))  # Cholesky factor, band entries only
    y = np.empty(n_bones)
    ridge = rho2 / gamma
    for t in range(n_frames):
        for b in range(n_bones):
            for c in range(3):
                u[b, c] = N[t, bi[b], c] - N[t, bj[b], c]
        # g = -Z2 - rho2 (N - A) - gamma J^T F
        for s in range(n_joints):
            for c in range(3):
                g[s, c] = -Z2[t, s, c] - rho2 * (N[t, s, c] - A[t, s, c])
        for b in range(n_bones):
            f = u[b, 0] * u[b, 0] + u[b, 1] * u[b, 1] + u[b, 2] * u[b, 2] - sq_lengths[b]
            for c in range(3):
                v = gamma * (2.0 * u[b, c] * f)
                g[bi[b], c] -= v
                g[bj[b], c] += v
        # J g
        for b in range(n_bones):
            acc = 0.0
            for c in range(3):
                acc += u[b, c] * (g[bi[b], c] - g[bj[b], c])
            y[b] = 2.0 * acc
        # banded Cholesky K = U^T U, K[k-d, k] = 4 diags[d, k-d] u_{k-d} . u_k (+ ridge on d = 0)
        for k in range(n_bones):
            lo = max(0, k - kb)
            for r in range(lo, k + 1):
                d = k - r
                kv = 4.0 * diags[d, r] * (u[r, 0] * u[k, 0] + u[r, 1] * u[k, 1] + u[r, 2] * u[k, 2])
                if d == 0:
                    kv += ridge
                for q in range(max(lo, r - kb), r):
                    kv -= U[q, r] * U[q, k]
                if r == k:
                    if not kv > 0.0:
                        return False  # not positive definite (or NaN): the caller uses LAPACK
                    U[k, k] = np.sqrt(kv)
                else:
                    U[r, k] = kv / U[r, r]
        # solve U^T z = Jg, then U y = z
        for k in range(n_bones):
            acc = y[k]
            for q in range(max(0, k - kb), k):
                acc -= U[q, k] * y[q]
            y[k] = acc / U[k, k]
        for k in range(n_bones - 1, -1, -1):
            acc = y[k]
            for q in range(k + 1, min(n_bones, k + kb + 1)):
                acc -= U[k, q] * y[q]
            y[k] = acc / U[k, k]
        # delta = (g - J^T y) / rho2 (Woodbury)
        for b in range(n_bones):
            for c in range(3):
                v = 2.0 * u[b, c] * y[b]
                g[bi[b], c] -= v
                g[bj[b], c] += v
        for s in range(n_joints):
            for c in range(3):
                out[t, s, c] = N[t, s, c] + g[s, c] / rho2
    return True


_gauss_newton_compiled = _jit(_gauss_newton_loop)


def gauss_newton_update(
    N: np.ndarray,
    A: np.ndarray,
    Z2: np.ndarray,
    rho2: float,
    gamma: float,
    bones: np.ndarray,
    bone_lengths: np.ndarray,
    band_diagonals: np.ndarray,
) -> np.ndarray | None:
    """One Gauss-Newton update of Eq. (20), compiled: the math of
    :func:`streamfix.core.isometry.gauss_newton_step` for bones already in its
    bandwidth-reducing order (``band_diagonals`` ``(kb + 1, B)``: row d holds the d-th
    diagonal of M M^T, zero-padded), one frame at a time with a banded Cholesky of K.
    Returns N + delta, or None when a K is not positive definite (the caller then uses
    LAPACK and its fallback). Needs numba (:data:`HAVE_NUMBA`)."""
    if _gauss_newton_compiled is None:
        raise RuntimeError("streamfix.core.kernels.gauss_newton_update needs numba; use isometry.gauss_newton_step")
    N = np.ascontiguousarray(N, dtype=np.float64)
    out = np.empty_like(N)
    b = np.asarray(bones, dtype=np.intp)
    ok = _gauss_newton_compiled(
        N, np.ascontiguousarray(A, dtype=np.float64), np.ascontiguousarray(Z2, dtype=np.float64),
        float(rho2), float(gamma), np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]),
        np.ascontiguousarray(bone_lengths, dtype=np.float64) ** 2, band_diagonals, out,
    )
    return out if ok else None


# --------------------------------------------------------------------------- robust temporal fit
def _tukey_weights_loop(y0, fit, obs, prior, c, w):  # pragma: no cover - compiled
    n_frames, n_ch = y0.shape
    for t in range(n_frames):
        for k in range(n_ch):
            r = y0[t, k] - fit[t, k]
            if obs[t, k] and abs(r) < c:
                q = r / c
                v = 1.0 - q * q
                w[t, k] = (v * v) * prior[t, k]
            else:
                w[t, k] = 0.0 * prior[t, k]


_tukey_weights_compiled = _jit(_tukey_weights_loop)


def robust_temporal_fit(
    positions: np.ndarray,
    weights: np.ndarray,
    h: int,
    scales_m: tuple[float, ...] = (0.10, 0.05, 0.02, 0.01),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 1 of the window cleaner, compiled: :func:`streamfix.core.robust_fit.robust_temporal_fit`
    (running-median start, Tukey reweighting at the graduated scales ``scales_m`` (m), local
    quadratic of half-width ``h`` frames) with the weights, median and fits in compiled
    loops and no per-pass temporaries. Same arguments and returns ``(fit, residual,
    support)`` ``(T, J, 3)``. Needs numba (:data:`HAVE_NUMBA`)."""
    if _tukey_weights_compiled is None:
        raise RuntimeError("streamfix.core.kernels.robust_temporal_fit needs numba; use streamfix.core.pipeline's")
    x = np.asarray(positions, dtype=np.float64)
    n_frames, n_joints, _ = x.shape
    y = np.ascontiguousarray(x.reshape(n_frames, 3 * n_joints))
    fit = np.empty_like(y)
    resid = np.empty_like(y)
    support = np.zeros_like(y)
    _robust_fit_compiled(
        y, np.ascontiguousarray(weights, dtype=np.float64), int(h), np.asarray(scales_m, dtype=np.float64),
        _poly_taps(int(h)), fit, resid, support,
    )
    shape = (n_frames, n_joints, 3)
    return fit.reshape(shape), resid.reshape(shape), support.reshape(shape)


def _robust_fit_loop(y, weights, h, scales, taps, fit, resid, support):  # pragma: no cover - compiled
    """:func:`robust_temporal_fit` on ``y`` ``(T, 3J)``, ``weights`` ``(T, J)``: one compiled call."""
    n_frames, n_ch = y.shape
    prior = np.empty((n_frames, n_ch))
    obs = np.empty((n_frames, n_ch), dtype=np.bool_)
    y0 = np.empty((n_frames, n_ch))
    ynan = np.empty((n_frames, n_ch))
    for t in range(n_frames):
        for k in range(n_ch):
            v = y[t, k]
            p = weights[t, k // 3] if np.isfinite(v) else 0.0
            prior[t, k] = p
            o = p > 0
            obs[t, k] = o
            y0[t, k] = v if o else 0.0
            ynan[t, k] = v if o else np.nan
    med = np.empty((n_frames, n_ch))
    _running_median_compiled(ynan, 2 * h + 1, med)
    cur = np.empty((n_frames, n_ch))
    for t in range(n_frames):
        for k in range(n_ch):
            cur[t, k] = med[t, k] if np.isfinite(med[t, k]) else 0.0
    w = np.empty((n_frames, n_ch))
    for c in scales:  # graduated non-convexity: wide basin first, then sharpen
        _tukey_weights_compiled(y0, cur, obs, prior, c, w)
        _local_poly_compiled(y0, w, taps, fit, support, _PIVOT_RTOL)
        for t in range(n_frames):
            for k in range(n_ch):
                if support[t, k] > 0:  # no inlier left at this scale: the wider one's estimate stands
                    cur[t, k] = fit[t, k]
    fit[:, :] = cur
    for t in range(n_frames):
        for k in range(n_ch):
            resid[t, k] = y0[t, k] - fit[t, k] if obs[t, k] else np.nan


_robust_fit_compiled = _jit(_robust_fit_loop, error_model="numpy")  # its local quadratics vectorise too


# --------------------------------------------------------------------------- Theil-Sen line (live gate)
def _sorted_median(buf, n):  # pragma: no cover - compiled
    """Median of buf[:n] (sorted in place by insertion; tiny n): 0.5 (lo + hi) as the reference."""
    for i in range(1, n):
        v = buf[i]
        k = i
        while k > 0 and buf[k - 1] > v:
            buf[k] = buf[k - 1]
            k -= 1
        buf[k] = v
    return 0.5 * (buf[(n - 1) // 2] + buf[n // 2])


_sorted_median_compiled = _jit(_sorted_median)


def _rank_median(buf, n):  # pragma: no cover - compiled
    """Median of buf[:n] (finite values) by counting ranks, 0.5 (lo + hi) as :func:`_sorted_median`:
    the same value bit for bit, ``buf`` unchanged. Why: the live gate's medians are of 7-21 values
    that arrive in a new order every frame, and the insertion sort's data-dependent branches
    mispredicted most of its time away; the n x n comparisons here are branch-free counts."""
    k1 = (n - 1) // 2
    k2 = n // 2
    lo = np.nan
    hi = np.nan
    for i in range(n):
        v = buf[i]
        below = 0
        at_most = 0
        for q in range(n):
            w = buf[q]
            below += w < v
            at_most += w <= v
        # v is the k-th smallest value (0-based) for every k in [below, at_most)
        if below <= k1 < at_most:
            lo = v
        if below <= k2 < at_most:
            hi = v
    return 0.5 * (lo + hi)


_rank_median_compiled = _jit(_rank_median)


def _detrended_edges_loop(x, window, out):  # pragma: no cover - compiled
    n, n_ch = x.shape
    half = window // 2
    span = min(window, n)
    k = min(half, n)
    pairs = np.empty(max(span * (span - 1) // 2, 1))
    vals = np.empty(2 * half + 1)
    for c in range(n_ch):
        for edge in range(2):
            base = 0 if edge == 0 else n - span
            m = 0
            for i in range(span):
                xi = x[base + i, c]
                for j in range(i + 1, span):
                    s = (x[base + j, c] - xi) / float(j - i)
                    if s == s:
                        pairs[m] = s
                        m += 1
            slope = _sorted_median_compiled(pairs, m) if m > 0 else 0.0
            f0 = 0 if edge == 0 else max(n - k, k)
            f1 = k if edge == 0 else n
            for f in range(f0, f1):
                q = 0
                for t in range(max(0, f - half), min(n, f + half + 1)):
                    v = x[t, c] - float(t - f) * slope
                    if v == v:
                        vals[q] = v
                        q += 1
                if q > 0:
                    out[f, c] = _sorted_median_compiled(vals, q)


_detrended_edges_compiled = _jit(_detrended_edges_loop)


DETRENDED_EDGES_MAX_WINDOW = 9
"""Longest window :func:`detrended_edges` is used for: its medians sort by insertion, which
beats numpy on the 5-frame median of 30 Hz data but not on the 21 frames of 120 Hz
(210 pairwise slopes per channel)."""


def detrended_edges(x: np.ndarray, med: np.ndarray, window: int) -> np.ndarray:
    """:func:`streamfix.core.filters._detrended_edges` compiled, bit for bit: ``med`` (a running
    median of ``x`` ``(T, ...)``) with its first and last ``window // 2`` frames replaced by
    medians of samples moved along each edge's Theil-Sen slope. Needs numba (:data:`HAVE_NUMBA`);
    meant for windows up to :data:`DETRENDED_EDGES_MAX_WINDOW`."""
    if _detrended_edges_compiled is None:
        raise RuntimeError("streamfix.core.kernels.detrended_edges needs numba; use streamfix.core.filters")
    x = np.asarray(x, dtype=np.float64)
    flat = np.ascontiguousarray(x.reshape(x.shape[0], -1))
    out = np.array(np.asarray(med, dtype=np.float64).reshape(flat.shape), order="C")
    if flat.size and window // 2 >= 1 and flat.shape[0] >= 3:
        _detrended_edges_compiled(flat, int(window), out)
    return out.reshape(x.shape)


def _theil_sen_loop(hist, u, pi, pj, r, sigma):  # pragma: no cover - compiled
    n_rows, n_joints, _ = hist.shape
    n_pairs = pi.shape[0]
    buf = np.empty(max(n_pairs, n_rows))
    for j in range(n_joints):
        for c in range(3):
            n_obs = 0
            for i in range(n_rows):
                if hist[i, j, c] == hist[i, j, c]:
                    n_obs += 1
            if n_obs < 3:
                r[j, c] = np.nan
                sigma[j, c] = np.nan
                continue
            m = 0
            for p in range(n_pairs):
                s = (hist[pj[p], j, c] - hist[pi[p], j, c]) / (u[pj[p]] - u[pi[p]])
                if s == s:
                    buf[m] = s
                    m += 1
            b = _rank_median_compiled(buf, m)
            m = 0
            for i in range(n_rows):
                v = hist[i, j, c] - b * u[i]
                if v == v:
                    buf[m] = v
                    m += 1
            a = _rank_median_compiled(buf, m)
            m = 0
            for i in range(n_rows):
                v = abs(hist[i, j, c] - (a + b * u[i]))
                if v == v:
                    buf[m] = v
                    m += 1
            sigma[j, c] = 1.4826 * _rank_median_compiled(buf, m)
            r[j, c] = a + b * u[n_rows - 1]


_theil_sen_compiled = _jit(_theil_sen_loop)


def theil_sen_line(hist: np.ndarray, u: np.ndarray, pi: np.ndarray, pj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The live gate's robust line, compiled: :meth:`streamfix.streaming.live.LivePath.robust_line`
    on ``hist`` ``(K, J, 3)`` m (NaN = missing) at abscissae ``u`` ``(K,)`` frames with the
    sample pairs ``(pi, pj)``: the line's value at the newest sample and its 1.4826 MAD
    scale, ``(J, 3)`` each (NaN with fewer than 3 samples), bit for bit. Needs numba."""
    if _theil_sen_compiled is None:
        raise RuntimeError("streamfix.core.kernels.theil_sen_line needs numba; use LivePath.robust_line")
    n_joints = hist.shape[1]
    r = np.empty((n_joints, 3))
    sigma = np.empty((n_joints, 3))
    _theil_sen_compiled(np.ascontiguousarray(hist, dtype=np.float64), u, pi, pj, r, sigma)
    return r, sigma


# --------------------------------------------------------------------------- live step (gate, One Euro, projection)
def _release_rigid_loop(x, valid, g, outlier, last, tree_p, tree_c, child_len, order, ratio, floor):  # pragma: no cover - compiled
    """:meth:`streamfix.streaming.live.LivePath._release_rigid`, the same sums in the same order."""
    n_bones = tree_p.shape[0]
    for i in range(order.shape[0]):
        j = order[i]
        if not valid[j] or not (outlier[j, 0] or outlier[j, 1] or outlier[j, 2]):
            continue
        e_raw = 0.0
        e_rep = 0.0
        n = 0.0
        for side in range(2):
            for b in range(n_bones):
                if side == 0:
                    if tree_p[b] != j:
                        continue
                    k = tree_c[b]
                else:
                    if tree_c[b] != j:
                        continue
                    k = tree_p[b]
                length = child_len[tree_c[b]]
                if not np.isfinite(length):
                    d0 = last[tree_c[b], 0] - last[tree_p[b], 0]
                    d1 = last[tree_c[b], 1] - last[tree_p[b], 1]
                    d2 = last[tree_c[b], 2] - last[tree_p[b], 2]
                    length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                if not np.isfinite(length):
                    continue
                if side == 0 and valid[k]:  # a child not judged yet: raw; the parent as judged
                    k0, k1, k2 = x[k, 0], x[k, 1], x[k, 2]
                else:
                    k0, k1, k2 = g[k, 0], g[k, 1], g[k, 2]
                if not (np.isfinite(k0) and np.isfinite(k1) and np.isfinite(k2)):
                    continue
                if not (np.isfinite(g[k, 0]) and np.isfinite(g[k, 1]) and np.isfinite(g[k, 2])):
                    continue
                d0 = x[j, 0] - k0
                d1 = x[j, 1] - k1
                d2 = x[j, 2] - k2
                e_raw += abs(np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - length)
                d0 = g[j, 0] - g[k, 0]
                d1 = g[j, 1] - g[k, 1]
                d2 = g[j, 2] - g[k, 2]
                e_rep += abs(np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) - length)
                n += 1.0
        if n == 0.0:
            continue
        e_raw = e_raw / max(n, 1.0)
        e_rep = e_rep / max(n, 1.0)
        if e_raw <= ratio * e_rep and e_rep > floor:
            for c in range(3):
                g[j, c] = x[j, c]
                outlier[j, c] = False


_release_rigid_compiled = _jit(_release_rigid_loop)


def _live_step_loop(
    x, valid, t, hist, u, pi, pj, scale, last, fx, fdx, ft, fseen,
    min_cutoff, beta, d_cutoff, gate_min_m, gate_k, tree_p, tree_c, child_len, project, project_tracked, y_out,
    outlier, order, release_ratio, release_floor,
):  # pragma: no cover - compiled
    n_rows, n_joints, _ = hist.shape
    # the raw history moves up one row; the newest row is this frame (NaN where invalid)
    for i in range(n_rows - 1):
        for j in range(n_joints):
            for c in range(3):
                hist[i, j, c] = hist[i + 1, j, c]
    for j in range(n_joints):
        for c in range(3):
            hist[n_rows - 1, j, c] = x[j, c] if valid[j] else np.nan
    r = np.empty((n_joints, 3))
    sigma = np.empty((n_joints, 3))
    _theil_sen_compiled(hist, u, pi, pj, r, sigma)
    g = np.empty((n_joints, 3))
    n_gated = 0
    for j in range(n_joints):
        for c in range(3):
            have_ref = np.isfinite(r[j, c])
            innov = abs(x[j, c] - r[j, c])
            if np.isfinite(sigma[j, c]):  # residual scale, EMA over ~10 frames
                if np.isfinite(scale[j, c]):
                    scale[j, c] = 0.9 * scale[j, c] + 0.1 * sigma[j, c]
                else:
                    scale[j, c] = sigma[j, c]
            s = scale[j, c] if np.isfinite(scale[j, c]) else gate_min_m
            tau = max(gate_min_m, gate_k * s)
            out = valid[j] and have_ref and innov > tau
            outlier[j, c] = out
            if valid[j] and not out:
                g[j, c] = x[j, c]
            elif have_ref:
                g[j, c] = r[j, c]
            else:
                g[j, c] = last[j, c]
    if release_ratio >= 0.0 and tree_p.shape[0] > 0:
        _release_rigid_compiled(x, valid, g, outlier, last, tree_p, tree_c, child_len, order, release_ratio, release_floor)
    for j in range(n_joints):
        if outlier[j, 0] or outlier[j, 1] or outlier[j, 2]:
            n_gated += 1
    # One Euro (Casiez et al. 2012), per joint with a finite gated sample
    for j in range(n_joints):
        ok = np.isfinite(g[j, 0]) and np.isfinite(g[j, 1]) and np.isfinite(g[j, 2])
        if not ok:
            continue
        if not fseen[j]:
            for c in range(3):
                fx[j, c] = g[j, c]
                fdx[j, c] = 0.0
            ft[j] = t
            fseen[j] = True
            continue
        dt = max(t - ft[j], 1e-6)
        a_d = 1.0 / (1.0 + (1.0 / (2.0 * np.pi * d_cutoff)) / dt)
        for c in range(3):
            x_prev = fx[j, c]
            dx = (g[j, c] - x_prev) / dt
            dx_hat = a_d * dx + (1.0 - a_d) * fdx[j, c]
            cutoff = min_cutoff + beta * abs(dx_hat)
            a = 1.0 / (1.0 + (1.0 / (2.0 * np.pi * cutoff)) / dt)
            fx[j, c] = a * g[j, c] + (1.0 - a) * x_prev
            fdx[j, c] = dx_hat
        ft[j] = t
    for j in range(n_joints):
        for c in range(3):
            y_out[j, c] = fx[j, c] if np.isfinite(fx[j, c]) else last[j, c]
    if project:
        # each child at its bone length from its unprojected parent, along the bone
        y = y_out.copy()
        for b in range(tree_p.shape[0]):
            p = tree_p[b]
            q = tree_c[b]
            if not project_tracked and valid[q] and not (outlier[q, 0] or outlier[q, 1] or outlier[q, 2]):
                continue  # a tracked joint the gate accepted stays where it was measured
            v0 = y[q, 0] - y[p, 0]
            v1 = y[q, 1] - y[p, 1]
            v2 = y[q, 2] - y[p, 2]
            norm = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)  # the order of np.linalg.norm's sum
            target = child_len[q]
            k = 1.0
            if np.isfinite(target) and norm > 1e-9 and np.isfinite(norm):
                k = target / norm
            n0 = y[p, 0] + v0 * k
            n1 = y[p, 1] + v1 * k
            n2 = y[p, 2] + v2 * k
            if np.isfinite(n0) and np.isfinite(n1) and np.isfinite(n2):
                y_out[q, 0] = n0
                y_out[q, 1] = n1
                y_out[q, 2] = n2
    return n_gated


_live_step_compiled = _jit(_live_step_loop)


def live_step(
    x: np.ndarray, valid: np.ndarray, t: float, hist: np.ndarray, u: np.ndarray, pi: np.ndarray, pj: np.ndarray,
    scale: np.ndarray, last: np.ndarray, filter_state: tuple, params: tuple, tree_parent: np.ndarray,
    tree_child: np.ndarray, child_len: np.ndarray, project: bool, project_tracked: bool, release: tuple,
) -> tuple[np.ndarray, np.ndarray, int]:
    """One frame of the live path's default chain, compiled: the Theil-Sen gate, the One
    Euro filter and the non-propagating bone projection of
    :meth:`streamfix.streaming.live.LivePath.step` in one call, bit for bit.

    ``x`` ``(J, 3)`` m, ``valid`` ``(J,)``, ``t`` s. The state arrays are updated in place:
    ``hist`` ``(K, J, 3)`` raw samples, ``scale`` ``(J, 3)`` m,
    ``filter_state`` = the One Euro filter's ``(x, dx, t, seen)``; ``last`` ``(J, 3)`` m, the
    previous output (read only). ``params`` =
    ``(min_cutoff Hz, beta, d_cutoff Hz, gate_min_m m, gate_k)``; ``tree_parent``,
    ``tree_child`` ``(k,)`` the tree's bones; ``child_len`` ``(J,)`` m. ``project_tracked``
    False: the projection moves only joints missing or gated. ``release`` = ``(joints
    roots first, ratio, floor m)`` of the rigid release (a negative ratio: none). Returns ``(positions (J, 3),
    outlier (J, 3) bool, joints gated)``. Needs numba (:data:`HAVE_NUMBA`).
    """
    if _live_step_compiled is None:
        raise RuntimeError("streamfix.core.kernels.live_step needs numba; use LivePath.step's numpy path")
    n_joints = hist.shape[1]
    y = np.empty((n_joints, 3))
    outlier = np.empty((n_joints, 3), dtype=np.bool_)
    fx, fdx, ft, fseen = filter_state
    min_cutoff, beta, d_cutoff, gate_min_m, gate_k = params
    n = _live_step_compiled(
        np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(valid, dtype=np.bool_), float(t),
        hist, u, pi, pj, scale, last, fx, fdx, ft, fseen,
        float(min_cutoff), float(beta), float(d_cutoff), float(gate_min_m), float(gate_k),
        tree_parent, tree_child, child_len, bool(project), bool(project_tracked), y, outlier,
        release[0], float(release[1]), float(release[2]),
    )
    return y, outlier, int(n)


def _live_carry_loop(live, raw, valid, held, level, offset, parent, order, fade_frames, min_m, out, rec):  # pragma: no cover - compiled
    J = live.shape[0]
    carried = live.copy()
    for k in range(J):
        c = order[k]
        for a in range(3):
            out[c, a] = live[c, a]
        if not held[c] and level[c] == 0:
            continue
        p = parent[c]
        for a in range(3):
            carried[c, a] = carried[p, a] + offset[c, a]
        if valid[c] and np.isfinite(raw[c, 0]) and np.isfinite(raw[c, 1]) and np.isfinite(raw[c, 2]):
            d0 = raw[c, 0] - carried[c, 0]
            d1 = raw[c, 1] - carried[c, 1]
            d2 = raw[c, 2] - carried[c, 2]
            if np.sqrt(d0 * d0 + d1 * d1 + d2 * d2) < min_m:
                held[c] = False
        lv = level[c] + (1 if held[c] else -1)
        lv = min(max(lv, 0), fade_frames)
        level[c] = lv
        w = lv / fade_frames
        for a in range(3):
            out[c, a] = live[c, a] + w * (carried[c, a] - live[c, a])
        if lv > 0:
            rec[c] = True


_live_carry_compiled = _jit(_live_carry_loop)


def live_carry(live: np.ndarray, raw: np.ndarray, valid: np.ndarray, recovered: np.ndarray, held: np.ndarray,
               level: np.ndarray, offset: np.ndarray, parent: np.ndarray, order: np.ndarray, fade_frames: int,
               min_m: float) -> tuple[np.ndarray, np.ndarray]:
    """One live frame with the windows' verdict carried on, compiled: the body of
    :meth:`streamfix.streaming.live_carry.WindowCarry.apply` after its bookkeeping, bit for bit.

    ``live`` ``(J, 3)`` m the live path's frame, ``raw`` ``(J, 3)`` / ``valid`` ``(J,)`` the
    sensor's; ``held`` ``(J,)`` bool and ``level`` ``(J,)`` int64, the carry's state, updated in
    place; ``offset`` ``(J, 3)`` m from each joint's ``parent`` ``(J,)``; ``order`` ``(J,)`` every
    joint, parents first. Returns ``(positions (J, 3), recovered (J,))``. Needs numba.
    """
    if _live_carry_compiled is None:
        raise RuntimeError("streamfix.core.kernels.live_carry needs numba; use WindowCarry.apply's numpy path")
    out = np.empty_like(live, dtype=np.float64)
    rec = np.array(recovered, dtype=np.bool_)
    _live_carry_compiled(np.ascontiguousarray(live, dtype=np.float64), np.ascontiguousarray(raw, dtype=np.float64),
                         np.ascontiguousarray(valid, dtype=np.bool_), held, level, offset, parent, order,
                         int(fade_frames), float(min_m), out, rec)
    return out, rec


# --------------------------------------------------------------------------- bone spread
def _select_inplace(a, n, k):  # pragma: no cover - compiled
    """The k-th smallest of ``a[:n]`` (no NaN), partially reordering ``a[:n]`` in place so
    that ``a[:k]`` holds values <= it (Hoare's selection, median-of-three pivot): the value
    a full sort would put at ``k``, in O(n) instead of O(n log n)."""
    lo = 0
    hi = n - 1
    while hi > lo:
        mid = (lo + hi) // 2
        if a[mid] < a[lo]:
            a[mid], a[lo] = a[lo], a[mid]
        if a[hi] < a[lo]:
            a[hi], a[lo] = a[lo], a[hi]
        if a[hi] < a[mid]:
            a[hi], a[mid] = a[mid], a[hi]
        pivot = a[mid]
        i = lo
        j = hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return a[k]
    return a[k]


_select_inplace_compiled = _jit(_select_inplace)


def _select_median(a, n):  # pragma: no cover - compiled
    """Median of ``a[:n]`` (n >= 1, no NaN) as a sort gives it, ``(s[(n-1)//2] + s[n//2]) / 2``,
    by selection; reorders ``a[:n]``."""
    upper = _select_inplace_compiled(a, n, n // 2)
    if n % 2:
        return (upper + upper) / 2.0
    lower = a[0]
    for i in range(1, n // 2):  # a[:n//2] holds the values <= upper: its largest is s[n//2 - 1]
        if a[i] > lower:
            lower = a[i]
    return (lower + upper) / 2.0


_select_median_compiled = _jit(_select_median)


def _bone_spread_loop(positions, observed, bi, bj, min_bone_m, devs, frame_dev, want_frames):  # pragma: no cover - compiled
    n_frames = positions.shape[0]
    lengths = np.empty(n_frames)
    buf = np.empty(n_frames)
    for b in range(bi.shape[0]):
        i = bi[b]
        j = bj[b]
        for t in range(n_frames):
            if observed[t, i] and observed[t, j]:
                d0 = positions[t, i, 0] - positions[t, j, 0]
                d1 = positions[t, i, 1] - positions[t, j, 1]
                d2 = positions[t, i, 2] - positions[t, j, 2]
                lengths[t] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            else:
                lengths[t] = np.nan
        n = 0
        for t in range(n_frames):
            if lengths[t] == lengths[t]:
                buf[n] = lengths[t]
                n += 1
        devs[b] = np.nan
        if n == 0:
            continue
        typical = _select_median_compiled(buf, n)  # in place: no array allocated per bone
        if not typical > min_bone_m:
            continue
        n = 0
        for t in range(n_frames):
            if lengths[t] == lengths[t]:
                buf[n] = abs(lengths[t] - typical)
                n += 1
        devs[b] = _select_median_compiled(buf, n)
        if want_frames:
            for t in range(n_frames):
                frame_dev[t, b] = abs(lengths[t] - typical)  # NaN where the bone is not seen


_bone_spread_compiled = _jit(_bone_spread_loop)


def bone_spread_deviations(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray, min_bone_m: float,
                           frames: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Per bone ``(B,)``: median over frames of ``|l_t - median_t l|`` (m), NaN for a bone whose
    typical length is not above ``min_bone_m`` or that is never seen: the deviations
    :func:`streamfix.core.pipeline._bone_spread` averages, bit for bit (lengths where both
    ends are ``observed`` ``(T, J)``). ``frames=True`` also returns the per-frame deviations
    ``|l_t - median_t l|`` ``(T, B)`` from the same lengths (NaN where the bone is not seen and
    in the columns of bones whose per-bone value is NaN). Needs numba (:data:`HAVE_NUMBA`)."""
    if _bone_spread_compiled is None:
        raise RuntimeError("streamfix.core.kernels.bone_spread_deviations needs numba; use pipeline._bone_spread")
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    devs = np.empty(len(b))
    x = np.ascontiguousarray(positions, dtype=np.float64)
    frame_dev = np.full((x.shape[0], len(b)) if frames else (1, 1), np.nan)
    _bone_spread_compiled(
        x, np.ascontiguousarray(observed, dtype=np.bool_),
        np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]), float(min_bone_m), devs, frame_dev, bool(frames),
    )
    return (devs, frame_dev) if frames else devs


# --------------------------------------------------------------------------- shorth mode
def _sorted_shorth_mode(s, fraction):  # pragma: no cover - compiled
    """The shorth mode of the ascending finite samples ``s`` (at least one)."""
    n = len(s)
    h = max(int(np.ceil(fraction * n)), 1)
    best = 0
    best_width = np.inf
    for i in range(n - h + 1):
        width = s[i + h - 1] - s[i]
        if width < best_width:  # the first of equal widths, as argmin
            best_width = width
            best = i
    return s[min(best + (h - 1) // 2, n - 1)]


_sorted_shorth_mode_compiled = _jit(_sorted_shorth_mode)


def _sorted_densest_mode(s, half_width):  # pragma: no cover - compiled
    """:func:`streamfix.core.isometry.densest_mode` of the ascending finite samples ``s`` (at
    least one): the counts within ``half_width`` by two pointers, as the reference's searches."""
    n = len(s)
    count = np.empty(n, dtype=np.int64)
    lo = 0
    hi = 0
    best = 0
    for i in range(n):
        while hi < n and s[hi] <= s[i] + half_width:
            hi += 1
        while s[lo] < s[i] - half_width:
            lo += 1
        count[i] = hi - lo
        best = max(best, hi - lo)
    ties = 0
    for i in range(n):
        ties += count[i] == best
    want = ties // 2  # the middle one of the tied samples
    for i in range(n):
        if count[i] == best:
            if want == 0:
                return s[i]
            want -= 1
    return s[n - 1]


_sorted_densest_mode_compiled = _jit(_sorted_densest_mode)


def _sorted_finite(values, b, buf):  # pragma: no cover - compiled
    """Column ``b``'s finite values, sorted ascending in ``buf[:n]``; returns ``n``."""
    n = 0
    for t in range(values.shape[0]):
        v = values[t, b]
        if np.isfinite(v):
            buf[n] = v
            n += 1
    buf[:n].sort()  # in place: no array allocated per column
    return n


_sorted_finite_compiled = _jit(_sorted_finite)


def _shorth_mode_loop(values, fraction, out):  # pragma: no cover - compiled
    buf = np.empty(values.shape[0])
    for b in range(values.shape[1]):
        n = _sorted_finite_compiled(values, b, buf)
        out[b] = _sorted_shorth_mode_compiled(buf[:n], fraction) if n else np.nan


_shorth_mode_compiled = _jit(_shorth_mode_loop)


def shorth_mode(values: np.ndarray, fraction: float) -> np.ndarray:
    """Per column of ``values`` ``(T, B)`` (NaN = no sample), the middle of the shortest
    interval holding ``fraction`` of the finite values: :func:`streamfix.core.isometry._shorth_mode`
    bit for bit (one sort of each column's samples, no ``(T, B)`` temporaries). Needs numba."""
    if _shorth_mode_compiled is None:
        raise RuntimeError("streamfix.core.kernels.shorth_mode needs numba; use isometry._shorth_mode")
    values = np.ascontiguousarray(values, dtype=np.float64)
    out = np.empty(values.shape[1])
    _shorth_mode_compiled(values, float(fraction), out)
    return out


def _length_mode_loop(values, half_width, refine, tol, lengths, support):  # pragma: no cover - compiled
    buf = np.empty(values.shape[0])
    for b in range(values.shape[1]):
        n = _sorted_finite_compiled(values, b, buf)
        if n == 0:
            lengths[b] = np.nan
            support[b] = 0
            continue
        s = buf[:n]
        est = _sorted_densest_mode_compiled(s, half_width)
        if refine >= 0.0:  # the median of the samples within refine of the mode: a run of s
            lo, hi = 0, n
            while lo < n and not abs(s[lo] - est) <= refine:
                lo += 1
            while hi > lo and not abs(s[hi - 1] - est) <= refine:
                hi -= 1
            if hi > lo:  # already sorted: the insertion sort only reads it
                est = _sorted_median_compiled(s[lo:hi], hi - lo)
        count = 0
        for i in range(n):
            if abs(s[i] - est) <= tol:
                count += 1
        lengths[b] = est
        support[b] = count


_length_mode_compiled = _jit(_length_mode_loop)


def length_mode_with_support(
    values: np.ndarray, half_width_m: float, tolerance_m: float, refine_m: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`streamfix.core.isometry.length_mode_with_support` of ``values`` ``(T, B)``
    (metres, NaN = no sample), bit for bit, from one sort per column: the densest mode,
    the median of the sorted run within ``refine_m`` of it, the count within
    ``tolerance_m``. The engine calls it every window on 10 s of bone lengths. Needs numba."""
    if _length_mode_compiled is None:
        raise RuntimeError("streamfix.core.kernels.length_mode_with_support needs numba; use isometry's")
    values = np.ascontiguousarray(values, dtype=np.float64)
    lengths = np.empty(values.shape[1])
    support = np.empty(values.shape[1], dtype=np.int64)
    refine = -1.0 if refine_m is None else float(refine_m)
    _length_mode_compiled(values, float(half_width_m), refine, float(tolerance_m), lengths, support)
    return lengths, support


# --------------------------------------------------------------------------- Kabsch rotations
def _kabsch_loop(H, out):  # pragma: no cover - compiled
    """Per ``H[t]`` (3x3): ``out[t] = U V^T`` from ``H = U S V^T`` with ``U``, ``V`` proper
    rotations (the last singular value carries the sign of ``det H``), which is Kabsch's
    rotation with its reflection fix. ``V``: eigenvectors of ``H^T H`` by cyclic Jacobi,
    its third column ``v1 x v2``; ``U``: ``H v1``, ``H v2`` orthonormalised, ``u1 x u2``."""
    n = H.shape[0]
    A = np.empty((3, 3))
    V = np.empty((3, 3))
    for t in range(n):
        scale = 0.0
        for i in range(3):
            for j in range(3):
                v = abs(H[t, i, j])
                if not v <= scale:  # NaN too
                    scale = v
        if not (scale > 0.0 and scale < np.inf):
            for i in range(3):
                for j in range(3):
                    out[t, i, j] = (1.0 if i == j else 0.0) if scale == 0.0 else np.nan
            continue
        inv = 1.0 / scale
        for i in range(3):
            for j in range(i, 3):
                s = 0.0
                for k in range(3):
                    s += (H[t, k, i] * inv) * (H[t, k, j] * inv)
                A[i, j] = s
                A[j, i] = s
                V[i, j] = 1.0 if i == j else 0.0
                V[j, i] = V[i, j]
        for sweep in range(32):
            off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
            if off <= 1e-36 * (A[0, 0] * A[0, 0] + A[1, 1] * A[1, 1] + A[2, 2] * A[2, 2]):
                break
            for p in range(2):
                for q in range(p + 1, 3):
                    apq = A[p, q]
                    if apq == 0.0:
                        continue
                    theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                    tt = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                    c = 1.0 / np.sqrt(tt * tt + 1.0)
                    s = tt * c
                    for k in range(3):
                        akp = A[k, p]
                        akq = A[k, q]
                        A[k, p] = c * akp - s * akq
                        A[k, q] = s * akp + c * akq
                    for k in range(3):
                        apk = A[p, k]
                        aqk = A[q, k]
                        A[p, k] = c * apk - s * aqk
                        A[q, k] = s * apk + c * aqk
                    for k in range(3):
                        vkp = V[k, p]
                        vkq = V[k, q]
                        V[k, p] = c * vkp - s * vkq
                        V[k, q] = s * vkp + c * vkq
        i1 = 0
        if A[1, 1] > A[i1, i1]:
            i1 = 1
        if A[2, 2] > A[i1, i1]:
            i1 = 2
        i2 = 1 if i1 == 0 else 0
        for i in range(3):
            if i != i1 and A[i, i] > A[i2, i2]:
                i2 = i
        v10, v11, v12 = V[0, i1], V[1, i1], V[2, i1]
        v20, v21, v22 = V[0, i2], V[1, i2], V[2, i2]
        v30, v31, v32 = v11 * v22 - v12 * v21, v12 * v20 - v10 * v22, v10 * v21 - v11 * v20
        b10 = H[t, 0, 0] * v10 + H[t, 0, 1] * v11 + H[t, 0, 2] * v12
        b11 = H[t, 1, 0] * v10 + H[t, 1, 1] * v11 + H[t, 1, 2] * v12
        b12 = H[t, 2, 0] * v10 + H[t, 2, 1] * v11 + H[t, 2, 2] * v12
        b20 = H[t, 0, 0] * v20 + H[t, 0, 1] * v21 + H[t, 0, 2] * v22
        b21 = H[t, 1, 0] * v20 + H[t, 1, 1] * v21 + H[t, 1, 2] * v22
        b22 = H[t, 2, 0] * v20 + H[t, 2, 1] * v21 + H[t, 2, 2] * v22
        n1 = np.sqrt(b10 * b10 + b11 * b11 + b12 * b12)
        u10, u11, u12 = b10 / n1, b11 / n1, b12 / n1
        d = u10 * b20 + u11 * b21 + u12 * b22
        b20 -= d * u10
        b21 -= d * u11
        b22 -= d * u12
        n2 = np.sqrt(b20 * b20 + b21 * b21 + b22 * b22)
        if not n2 > 1e-12 * n1:  # rank 1: any direction perpendicular to u1
            a0, a1, a2 = 0.0, 0.0, 0.0
            if abs(u10) <= abs(u11) and abs(u10) <= abs(u12):
                a0 = 1.0
            elif abs(u11) <= abs(u12):
                a1 = 1.0
            else:
                a2 = 1.0
            d = u10 * a0 + u11 * a1 + u12 * a2
            b20, b21, b22 = a0 - d * u10, a1 - d * u11, a2 - d * u12
            n2 = np.sqrt(b20 * b20 + b21 * b21 + b22 * b22)
        u20, u21, u22 = b20 / n2, b21 / n2, b22 / n2
        u30, u31, u32 = u11 * u22 - u12 * u21, u12 * u20 - u10 * u22, u10 * u21 - u11 * u20
        out[t, 0, 0] = u10 * v10 + u20 * v20 + u30 * v30
        out[t, 0, 1] = u10 * v11 + u20 * v21 + u30 * v31
        out[t, 0, 2] = u10 * v12 + u20 * v22 + u30 * v32
        out[t, 1, 0] = u11 * v10 + u21 * v20 + u31 * v30
        out[t, 1, 1] = u11 * v11 + u21 * v21 + u31 * v31
        out[t, 1, 2] = u11 * v12 + u21 * v22 + u31 * v32
        out[t, 2, 0] = u12 * v10 + u22 * v20 + u32 * v30
        out[t, 2, 1] = u12 * v11 + u22 * v21 + u32 * v31
        out[t, 2, 2] = u12 * v12 + u22 * v22 + u32 * v32


_kabsch_compiled = _jit(_kabsch_loop)


def kabsch_rotations(H: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` rotations ``R`` maximising ``tr(R^T H_t)`` for ``H`` ``(N, 3, 3)``
    (``H_t = P_t^T Q``: ``R`` minimises ``|P_t R - Q|``): the rotations of
    :func:`streamfix.core.pca_normalise.kabsch_svd`, to rounding, without numpy's per-matrix
    LAPACK call (faster on a few hundred frames). Where the minimiser is not unique (``H`` of rank 1:
    collinear points) both return one of them, not necessarily the same. An all-zero
    ``H`` gives the identity, a non-finite one NaN. Needs numba (:data:`HAVE_NUMBA`)."""
    if _kabsch_compiled is None:
        raise RuntimeError("streamfix.core.kernels.kabsch_rotations needs numba; use pca_normalise.kabsch_svd")
    h = np.ascontiguousarray(H, dtype=np.float64).reshape(-1, 3, 3)
    out = np.empty_like(h)
    _kabsch_compiled(h, out)
    return out.reshape(np.shape(H))


# --------------------------------------------------------------------------- warm-up
# --------------------------------------------------------------------------- marker pair distances
def _pair_distances_loop(xt, ia, ib, out):  # pragma: no cover - compiled
    """``out[p, t]`` = the length of ``xt[ia[p], :, t] - xt[ib[p], :, t]`` (``xt`` ``(J, 3, T)``), a NaN
    coordinate difference taken as 0, the squares summed x, y, z in that order."""
    n_frames = xt.shape[2]
    for p in range(ia.shape[0]):
        a = ia[p]
        b = ib[p]
        for t in range(n_frames):
            d0 = xt[a, 0, t] - xt[b, 0, t]
            d1 = xt[a, 1, t] - xt[b, 1, t]
            d2 = xt[a, 2, t] - xt[b, 2, t]
            if np.isnan(d0):
                d0 = 0.0
            if np.isnan(d1):
                d1 = 0.0
            if np.isnan(d2):
                d2 = 0.0
            out[p, t] = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)


_pair_distances_compiled = _jit(_pair_distances_loop)


def pair_distances(x: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """:func:`streamfix.core.rigid_pairs.pair_distances_numpy` compiled, bit for bit and in the same
    memory order: the distance (m) of each marker pair ``(ia[p], ib[p])`` in every frame of ``x``
    ``(T, J, 3)``, ``(T, P)``. Why: the numpy reference gathers a ``(P, T, 3)`` array of
    differences, a take's worth for each of the thousands of pairs of an optical marker set.
    Needs numba (:data:`HAVE_NUMBA`)."""
    if _pair_distances_compiled is None:
        raise RuntimeError("streamfix.core.kernels.pair_distances needs numba; use streamfix.core.rigid_pairs'")
    xt = np.ascontiguousarray(np.asarray(x, dtype=np.float64).transpose(1, 2, 0))  # each coordinate's frames in a row
    ia = np.ascontiguousarray(ia, dtype=np.intp)
    ib = np.ascontiguousarray(ib, dtype=np.intp)
    out = np.empty((len(ia), xt.shape[2]))
    if out.size:
        _pair_distances_compiled(xt, ia, ib, out)
    return out.T


def warm_up() -> None:
    """Compile (or load from the disk cache) every kernel now, on tiny inputs.

    A kernel compiles on its first call: slowly the first time after an install, faster
    from the cache. A live service calls this before its first frame, so neither
    the first live frame nor the first window pays it. A no-op when :data:`COMPILED` is False.
    """
    if not COMPILED:
        return
    rng = np.random.default_rng(0)
    x = rng.normal(size=(12, 3, 3))
    x[2, 1] = np.nan
    w = np.ones((12, 9))
    bones = np.array([[0, 1], [1, 2]])
    lengths = np.array([0.5, 0.5])
    local_poly(np.nan_to_num(x.reshape(12, 9)), w, 2)
    running_median(x, 5)
    detrended_edges(x, x, 5)
    robust_temporal_fit(x, np.isfinite(x).all(axis=2).astype(float), 2)
    finite = np.nan_to_num(x)
    project_bone_lengths_pbd(finite, bones, lengths, 2)
    gauss_newton_update(finite, finite, np.zeros_like(finite), 1.0, 10.0, bones, lengths, np.ones((2, 2)))
    bone_spread_deviations(finite, np.ones((12, 3), dtype=bool), bones, 0.01)
    shorth_mode(x[:, :, 0], 0.5)
    length_mode_with_support(x[:, :, 0], 0.01, 0.005, 0.02)
    kabsch_rotations(finite)
    pair_distances(x, np.array([0, 0], dtype=np.intp), np.array([1, 2], dtype=np.intp))
    pi, pj = (np.ascontiguousarray(a) for a in np.triu_indices(7, 1))
    theil_sen_line(x[:7], np.arange(7.0), pi, pj)
    state = (np.full((3, 3), np.nan), np.zeros((3, 3)), np.zeros(3), np.zeros(3, dtype=bool))
    live_step(finite[0], np.ones(3, dtype=bool), 0.0, x[:7].copy(), np.arange(7.0), pi, pj, np.full((3, 3), np.nan),
              np.full((3, 3), np.nan), state, (1.0, 0.5, 1.0, 0.03, 4.0), bones[:, 0].copy(), bones[:, 1].copy(),
              np.full(3, 0.5), True, False, (np.arange(3, dtype=np.intp), 0.5, 0.003))
    idx = lambda *v: np.array(v, dtype=np.intp)  # noqa: E731
    prepared = (idx(0, 1, 2, 2), idx(0), idx(1), idx(0, 1), True, 5.0, 0.5, np.zeros(27), np.zeros((27, 3)),
                np.zeros((2, 6)), 1.0, 2.0, np.ones(1), np.ones((3, 1)), idx(0, 1), idx(1, 2), np.full((2, 1), 0.25),
                np.full((2, 1), 0.25), 2, 0.5)
    live_pose_bias(finite[0] + 1.0, prepared, None)
    live_carry(finite[0], finite[0], np.ones(3, dtype=bool), np.zeros(3, dtype=bool), np.array([False, True, False]),
               np.zeros(3, dtype=np.int64), np.zeros((3, 3)), idx(-1, 0, 1), idx(0, 1, 2), 3, 0.08)
