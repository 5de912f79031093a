"""Fast smoothing baselines: One Euro, Kinect SDK Holt filter, Savitzky-Golay, median + SG.

All positions are metres; ``(T, J, 3)`` for the batch functions, ``(J, 3)`` for one
frame of a streaming filter. A joint that is missing (``observed`` False, or a NaN
coordinate) never enters a filter's state: the streaming filters hold their last
output for it (NaN if it was never seen) and resume when it returns.

* :class:`OneEuroFilter` / :func:`one_euro` -- Casiez, Roussel & Vogel, "1 Euro
  filter: a simple speed-based low-pass filter for noisy input in interactive
  systems", CHI 2012. Adaptive first-order low-pass whose cutoff rises with speed:
  ``f_c = min_cutoff + beta * |dx_hat|``; rate-aware through the sample period.
* :class:`HoltFilter` / :func:`holt` -- the Kinect for Windows SDK joint filter
  (Holt double-exponential smoothing with a jitter-radius pre-filter, prediction and
  a max-deviation clamp). Parameters are ``TransformSmoothParameters``
  (``NUI_TRANSFORM_SMOOTH_PARAMETERS``); defaults are the SDK's documented defaults
  ``{Smoothing 0.5, Correction 0.5, Prediction 0.5, JitterRadius 0.05 m,
  MaxDeviationRadius 0.04 m}`` ("Some smoothing with little latency (defaults)",
  Kinect for Windows SDK 1.8 reference, NUI_TRANSFORM_SMOOTH_PARAMETERS,
  https://learn.microsoft.com/en-us/previous-versions/windows/kinect-1.8/hh855623(v=ieb.10);
  behaviour: "Joint Filtering", .../kinect-1.8/jj131024(v=ieb.10)). That page is
  inconsistent about Prediction: its member list says "the default value is 0.0",
  its example set labelled "(defaults)" uses 0.5; we follow the labelled set (the
  other four values agree) -- pass ``HoltParams(prediction=0.0)`` for the other
  reading. The update
  equations follow the SDK's sample ``KinectJointFilter.cpp`` (``FilterDoubleExponential``),
  including its rule that *inferred* joints use twice the two radii.
* :func:`savgol` -- Savitzky-Golay (``scipy.signal.savgol_filter``) along time.
* :func:`median_savgol` -- running median (outlier removal) followed by Savitzky-Golay.
* :func:`butterworth` -- zero-phase (forward-backward) Butterworth low-pass, the default
  of FreeMoCap and Pose2Sim (2nd order, 6 Hz cut-off).
* :func:`binomial_taps` -- the binomial kernel ``[1, 2, 1]^h / 4^h``: zero lag, zero gain
  at the Nyquist frequency (where frame-to-frame jitter lives), flat near 0 Hz;
  :func:`twiced_binomial_taps`, the same made exact for quadratic motion.

Window lengths are given in seconds and converted to odd frame counts at the rate,
so the same defaults mean the same time span at 30 Hz and at 120 Hz.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.ndimage import convolve1d

from . import kernels
from .interpolate import interpolate_linear, observed_mask
from .robust_stats import nanmedian

__all__ = [
    "exponential_smoothing",
    "OneEuroFilter",
    "HoltParams",
    "HoltFilter",
    "KINECT_SDK_DEFAULTS",
    "one_euro",
    "holt",
    "savgol",
    "median_savgol",
    "butterworth",
    "binomial_taps",
    "twiced_binomial_taps",
    "savgol_coefficients",
    "running_median",
    "odd_window",
]


def odd_window(window_s: float, rate_hz: float, minimum: int = 3) -> int:
    """An odd frame count spanning about ``window_s`` seconds at ``rate_hz`` (>= minimum)."""
    n = int(round(window_s * rate_hz))
    n = max(n, minimum)
    return n if n % 2 == 1 else n + 1


# --------------------------------------------------------------------------- One Euro
class OneEuroFilter:
    """Streaming One Euro filter over ``(J, 3)`` frames, vectorised across joints.

    Parameters (Casiez et al. 2012): ``min_cutoff`` (Hz) -- cutoff at rest, lower means
    less jitter and more lag; ``beta`` (1/m, i.e. Hz per m/s of speed) -- speed
    coefficient, higher means less lag on fast motion; ``d_cutoff`` (Hz) -- cutoff of the
    derivative's low-pass. ``rate_hz`` sets the nominal sample period; ``step`` may be
    given an explicit timestamp ``t`` (s) instead, so dropped frames are handled.
    """

    def __init__(
        self,
        rate_hz: float,
        min_cutoff: float = 1.0,
        beta: float = 0.5,
        d_cutoff: float = 1.0,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.rate_hz = float(rate_hz)
        self.min_cutoff = float(min_cutoff)
        self.beta = float(beta)
        self.d_cutoff = float(d_cutoff)
        self.reset()

    def reset(self) -> None:
        self._x: np.ndarray | None = None  # (J, 3) last filtered position
        self._dx: np.ndarray | None = None  # (J, 3) last filtered derivative (m/s)
        self._t: np.ndarray | None = None  # (J,) time of last update (s)
        self._seen: np.ndarray | None = None  # (J,) joint has state
        self._frame = 0

    @staticmethod
    def _alpha(cutoff: np.ndarray | float, dt: np.ndarray) -> np.ndarray:
        # alpha = 1 / (1 + tau / T_e), tau = 1 / (2 pi f_c)   (Casiez et al., Eq. 1-2)
        tau = 1.0 / (2.0 * np.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def step(self, positions: np.ndarray, observed: np.ndarray | None = None, t: float | None = None) -> np.ndarray:
        """Filter one frame ``(J, 3)`` (m); returns the filtered ``(J, 3)``."""
        x = np.asarray(positions, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"positions must be (J, 3), got {x.shape}")
        obs = observed_mask(x, observed)
        n_joints = x.shape[0]
        if t is None:
            t = self._frame / self.rate_hz
        self._frame += 1
        if self._x is None or self._x.shape[0] != n_joints:
            if self._x is not None:
                raise ValueError(f"filter was started with {self._x.shape[0]} joints, got {n_joints}")
            self._x = np.full((n_joints, 3), np.nan)
            self._dx = np.zeros((n_joints, 3))
            self._t = np.zeros(n_joints)
            self._seen = np.zeros(n_joints, dtype=bool)
        first = obs & ~self._seen
        upd = obs & self._seen
        if first.any():
            self._x[first] = x[first]
            self._dx[first] = 0.0
            self._t[first] = t
            self._seen[first] = True
        if upd.any():
            dt = np.maximum(t - self._t[upd], 1e-6)[:, None]  # (n, 1) s
            x_prev = self._x[upd]
            dx = (x[upd] - x_prev) / dt
            a_d = self._alpha(self.d_cutoff, dt)
            dx_hat = a_d * dx + (1.0 - a_d) * self._dx[upd]
            cutoff = self.min_cutoff + self.beta * np.abs(dx_hat)  # per coordinate
            a = self._alpha(cutoff, dt)
            self._x[upd] = a * x[upd] + (1.0 - a) * x_prev
            self._dx[upd] = dx_hat
            self._t[upd] = t
        return self._x.copy()


def one_euro(
    positions: np.ndarray,
    rate_hz: float,
    observed: np.ndarray | None = None,
    min_cutoff: float = 1.0,
    beta: float = 0.5,
    d_cutoff: float = 1.0,
) -> np.ndarray:
    """Causal One Euro filter over ``(T, J, 3)``; missing joints hold the last output."""
    positions = np.asarray(positions, dtype=np.float64)
    obs = observed_mask(positions, observed)
    f = OneEuroFilter(rate_hz, min_cutoff, beta, d_cutoff)
    out = np.empty_like(positions)
    for t in range(positions.shape[0]):  # recursive: loops over frames, vectorised over joints
        out[t] = f.step(positions[t], obs[t])
    return out


# --------------------------------------------------------------------------- Holt
@dataclass(frozen=True)
class HoltParams:
    """Kinect SDK ``TransformSmoothParameters`` (radii in metres, prediction in frames)."""

    smoothing: float = 0.5
    correction: float = 0.5
    prediction: float = 0.5
    jitter_radius: float = 0.05
    max_deviation_radius: float = 0.04


KINECT_SDK_DEFAULTS = HoltParams()


class HoltFilter:
    """Streaming Kinect SDK joint filter (Holt double exponential), vectorised across joints.

    Per joint, with raw position ``x``, previous filtered ``f'``, trend ``b'`` and the
    parameters ``(s, c, p, r_j, r_d)`` of :class:`HoltParams`:

    1. first frame: ``f = x, b = 0``; second: ``f = (x + x_prev)/2``, ``b = c (f - f') + (1-c) b'``;
    2. later: jitter pre-filter ``d = |x - f'|``; ``x~ = x d/r_j + f' (1 - d/r_j)`` if
       ``d <= r_j`` else ``x``; then ``f = (1-s) x~ + s (f' + b')``, ``b = c (f - f') + (1-c) b'``;
    3. prediction ``y = f + p b``; if ``|y - x| > r_d`` clamp ``y`` to the sphere of radius
       ``r_d`` around ``x``. ``y`` is the output.

    A missing joint resets that joint's history (as the SDK does for an untracked
    joint) and holds its last output. ``inferred`` joints use ``2 r_j`` and ``2 r_d``.
    """

    def __init__(self, params: HoltParams = KINECT_SDK_DEFAULTS) -> None:
        self.params = params
        self.reset()

    def reset(self) -> None:
        self._count: np.ndarray | None = None  # (J,) frames in history (0, 1, 2+)
        self._raw = self._filt = self._trend = self._out = None

    def step(
        self,
        positions: np.ndarray,
        observed: np.ndarray | None = None,
        inferred: np.ndarray | None = None,
    ) -> np.ndarray:
        """Filter one frame ``(J, 3)`` (m); returns the filter output ``(J, 3)``."""
        p = self.params
        x = np.asarray(positions, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"positions must be (J, 3), got {x.shape}")
        n_joints = x.shape[0]
        obs = observed_mask(x, observed)
        if self._count is None:
            self._count = np.zeros(n_joints, dtype=np.int64)
            self._raw = np.zeros((n_joints, 3))
            self._filt = np.zeros((n_joints, 3))
            self._trend = np.zeros((n_joints, 3))
            self._out = np.full((n_joints, 3), np.nan)
        elif self._count.shape[0] != n_joints:
            raise ValueError(f"filter was started with {self._count.shape[0]} joints, got {n_joints}")
        jr = np.full(n_joints, max(p.jitter_radius, 1e-4))  # SDK: epsilon 0.1 mm
        md = np.full(n_joints, p.max_deviation_radius)
        if inferred is not None:
            inf = np.asarray(inferred, dtype=bool)
            jr = np.where(inf, 2.0 * jr, jr)
            md = np.where(inf, 2.0 * md, md)

        self._count[~obs] = 0  # untracked joint: reset its history
        c0 = obs & (self._count == 0)
        c1 = obs & (self._count == 1)
        c2 = obs & (self._count >= 2)
        f = np.zeros((n_joints, 3))
        b = np.zeros((n_joints, 3))
        f[c0] = x[c0]
        f[c1] = 0.5 * (x[c1] + self._raw[c1])
        b[c1] = p.correction * (f[c1] - self._filt[c1]) + (1 - p.correction) * self._trend[c1]
        if c2.any():
            fp, bp, xr = self._filt[c2], self._trend[c2], x[c2]
            d = np.linalg.norm(xr - fp, axis=1)
            ratio = (d / jr[c2])[:, None]
            xj = np.where(ratio <= 1.0, xr * ratio + fp * (1.0 - ratio), xr)
            fn = xj * (1.0 - p.smoothing) + (fp + bp) * p.smoothing
            f[c2] = fn
            b[c2] = p.correction * (fn - fp) + (1.0 - p.correction) * bp
        y = f + b * p.prediction
        dev = np.linalg.norm(y - x, axis=1)
        over = obs & (dev > md)
        if over.any():
            k = (md[over] / dev[over])[:, None]
            y[over] = y[over] * k + x[over] * (1.0 - k)
        self._raw[obs] = x[obs]
        self._filt[obs] = f[obs]
        self._trend[obs] = b[obs]
        self._count[obs] += 1
        self._out[obs] = y[obs]
        return self._out.copy()


def holt(
    positions: np.ndarray,
    observed: np.ndarray | None = None,
    inferred: np.ndarray | None = None,
    params: HoltParams = KINECT_SDK_DEFAULTS,
) -> np.ndarray:
    """Causal Kinect SDK Holt filter over ``(T, J, 3)`` (m); missing joints hold the last output."""
    positions = np.asarray(positions, dtype=np.float64)
    obs = observed_mask(positions, observed)
    f = HoltFilter(params)
    out = np.empty_like(positions)
    for t in range(positions.shape[0]):  # recursive: loops over frames, vectorised over joints
        out[t] = f.step(positions[t], obs[t], None if inferred is None else inferred[t])
    return out


# --------------------------------------------------------------------------- offline filters
def _filled(positions: np.ndarray, observed: np.ndarray | None) -> np.ndarray:
    """``(T, J, 3)`` float64 with missing samples filled linearly (edges hold the nearest
    observation; a never-observed joint stays NaN): what the offline filters run on."""
    positions = np.asarray(positions, dtype=np.float64)
    filled, _ = interpolate_linear(positions, observed_mask(positions, observed))
    return filled


def _along_time(x: np.ndarray, smooth) -> np.ndarray:
    """``smooth(channels (T, n))`` applied to every channel of ``x`` that has data; a
    never-observed channel (NaN after gap filling) stays NaN."""
    seen = np.isfinite(x).all(axis=0)
    out = x.copy()
    if seen.any():
        out[:, seen] = smooth(x[:, seen])
    return out


def savgol(
    positions: np.ndarray,
    rate_hz: float,
    observed: np.ndarray | None = None,
    window_s: float = 0.3,
    polyorder: int = 3,
) -> np.ndarray:
    """Savitzky-Golay smoothing along time of ``(T, J, 3)`` (m), window ``window_s`` s.

    Missing samples are first filled by linear interpolation (edges hold the nearest
    observation) so that they neither poison the fit nor stay missing; a joint never
    observed stays NaN. A polynomial of degree <= ``polyorder`` passes unchanged.
    """
    x = _filled(positions, observed)
    n = x.shape[0]
    w = odd_window(window_s, rate_hz, minimum=polyorder + 2 if polyorder % 2 else polyorder + 1)
    if n < 2:
        return x.copy()
    if w > n:
        w = n if n % 2 == 1 else n - 1
    order = min(polyorder, w - 1)
    if w <= order or w < 3:
        return x.copy()
    return _along_time(x, lambda c: _savgol_interp(c, w, order))


def savgol_coefficients(window: int, order: int) -> np.ndarray:
    """``scipy.signal.savgol_coeffs(window, order)`` (smoothing, centred, for a convolution), by
    the same least-squares solve (LAPACK's gelsd through numpy: the same values bit for bit on the
    windows and orders tested). Why not scipy's: importing scipy.signal is a large share of
    ``streamfix clean``'s start, for these few coefficients."""
    half = window // 2
    x = np.arange(-half, window - half, dtype=np.float64)[::-1]  # convolution order
    A = x ** np.arange(order + 1).reshape(-1, 1)
    y = np.zeros(order + 1)
    y[0] = 1.0
    return np.linalg.lstsq(A, y, rcond=None)[0]


@lru_cache(maxsize=64)
def _savgol_plan(window: int, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Savitzky-Golay coefficients and the edge operators of scipy's ``mode='interp'``.

    scipy fits a degree-``order`` polynomial to the first / last ``window`` samples and
    evaluates it at the ``window // 2`` edge frames; that is a fixed linear map of those
    samples, ``(window // 2, window)`` per edge, computed once here instead of two
    least-squares fits per call.
    """
    coeffs = savgol_coefficients(window, order)
    half = window // 2
    u = np.arange(window, dtype=np.float64)
    fit = np.linalg.pinv(np.vander(u, order + 1))  # samples -> polynomial coefficients
    lo = np.vander(u[:half], order + 1) @ fit
    hi = np.vander(u[window - half:], order + 1) @ fit
    for a in (coeffs, lo, hi):
        a.setflags(write=False)
    return coeffs, lo, hi


def _savgol_interp(c: np.ndarray, window: int, order: int) -> np.ndarray:
    """``savgol_filter(c, window, order, axis=0, mode="interp")`` of ``c`` ``(T, n)``, the
    interior by the same convolution and the edges by :func:`_savgol_plan`'s operators
    (equal to scipy's to rounding: ~1e-15 m)."""
    coeffs, lo, hi = _savgol_plan(window, order)
    out = convolve1d(c, coeffs, axis=0, mode="constant")
    half = window // 2
    if half:
        out[:half] = lo @ c[:window]
        out[-half:] = hi @ c[-window:]
    return out


def running_median(
    positions: np.ndarray, window: int, observed: np.ndarray | None = None, *, detrend_edges: bool = True
) -> np.ndarray:
    """Centred running median over ``window`` frames (odd) of ``(T, ...)``, ignoring missing.

    Edges use the shrunken window (reflection is avoided: it would double-count edge
    samples), its samples moved along the edge's robust slope so that a moving joint is
    not lagged there (:func:`_detrended_edges`; ``detrend_edges=False`` keeps the plain
    one-sided median). An output sample is NaN only when its whole window is missing.

    Away from the edges, one sort of every window (NaN sorts last) and the count ``n`` of its
    observed samples give the median of any missing pattern: the middle sample for odd ``n``,
    the mean of the two middle ones for even ``n`` -- the same values as ``np.median``
    / ``np.nanmedian`` (bit for bit), and faster on a 60-frame window
    (``nanmedian`` of small arrays goes through masked arrays). With numba installed the
    compiled :func:`streamfix.core.kernels.running_median` (a sorted window per channel updated
    frame by frame, branch-free across channels for wide arrays) gives the same values bit for
    bit; this numpy version is its reference.
    """
    x = np.asarray(positions, dtype=np.float64).copy()
    if observed is not None:
        x[~observed_mask(x, observed)] = np.nan
    if kernels.COMPILED and x.ndim >= 1 and window >= 1:
        med = kernels.running_median(x, window)  # the same values, one sorted window per channel
    else:
        med = _running_median_numpy(x, window)
    if not detrend_edges:
        return med
    if kernels.COMPILED and x.ndim >= 1 and window <= kernels.DETRENDED_EDGES_MAX_WINDOW:
        return kernels.detrended_edges(x, med, window)  # the same values in one compiled pass
    return _detrended_edges(x, med, window)


def _detrended_edges(x: np.ndarray, med: np.ndarray, window: int) -> np.ndarray:
    """The first and last ``window // 2`` frames of a running median, made unbiased for a trend.

    There the window is one-sided, and its median is the middle of samples all on one
    side: on a joint moving at speed ``v`` it lags or leads by about ``v * (window // 2) / 2``
    (a Kinect foot at 4 m/s, a 5-frame window at 30 Hz: 13 cm at the first frame). Each
    edge frame instead takes the median of its shrunken window's samples moved along the
    edge's Theil-Sen slope (the median of the pairwise slopes over the first / last
    ``window`` frames, robust to a minority of outliers): the same robustness, no lag.
    Two sorts in all (:func:`streamfix.core.robust_stats.nanmedian`: the slopes of both
    edges, then every edge frame's window); channels and edge frames vectorised.
    """
    n = x.shape[0]
    if window // 2 < 1 or n < 3:
        return med
    plan = _edge_plan(n, window)
    tail = (None,) * (x.ndim - 1)  # broadcast over the channels
    pairs = (x[plan.second] - x[plan.first]) / plan.gap[(None, slice(None)) + tail]  # (2, P, ...)
    slopes = np.nan_to_num(nanmedian(pairs, axis=1))  # (2, ...) per edge
    moved = x[plan.samples] - plan.offsets[(slice(None), slice(None)) + tail] * slopes[plan.edge][:, None]
    moved[~plan.inside] = np.nan  # (edge frames, window, ...)
    m = nanmedian(moved, axis=1)
    out = med.copy()
    out[plan.frames] = np.where(np.isfinite(m), m, med[plan.frames])
    return out


class _EdgePlan(NamedTuple):
    first: np.ndarray  # (2, P) earlier sample of each pair, per edge span
    second: np.ndarray  # (2, P) later sample
    gap: np.ndarray  # (P,) frames between them
    frames: np.ndarray  # (F,) edge frames
    samples: np.ndarray  # (F, window) their window's sample indices (clipped)
    inside: np.ndarray  # (F, window) which of those exist
    offsets: np.ndarray  # (F, window) sample offset from the frame (frames)
    edge: np.ndarray  # (F,) 0 = first edge, 1 = last


@lru_cache(maxsize=256)
def _edge_plan(n: int, window: int) -> _EdgePlan:
    """Index arrays of :func:`_detrended_edges` for ``n`` frames and a ``window``."""
    half = window // 2
    span = min(window, n)
    i, j = np.triu_indices(span, k=1)
    k = min(half, n)
    start, end = np.arange(k), np.arange(max(n - k, k), n)
    frames = np.concatenate([start, end])
    offsets = np.arange(-half, half + 1)
    t = frames[:, None] + offsets[None, :]
    return _EdgePlan(
        first=np.stack([i, n - span + i]), second=np.stack([j, n - span + j]), gap=(j - i).astype(np.float64),
        frames=frames, samples=np.clip(t, 0, n - 1), inside=(t >= 0) & (t < n),
        offsets=np.broadcast_to(offsets.astype(np.float64), t.shape),
        edge=np.concatenate([np.zeros(len(start), np.intp), np.ones(len(end), np.intp)]),
    )


def _running_median_numpy(x: np.ndarray, window: int) -> np.ndarray:
    """:func:`running_median` of ``x`` (NaN = missing) in numpy: the reference of the
    compiled :func:`streamfix.core.kernels.running_median`."""
    half = window // 2
    n = x.shape[0]
    if n == 0:
        return x
    pad = np.full((half,) + x.shape[1:], np.nan)
    xp = np.concatenate([pad, x, pad], axis=0)
    win = np.sort(np.lib.stride_tricks.sliding_window_view(xp, window, axis=0)[:n], axis=-1)  # (T, ..., window)
    # observed samples per window, from a running count of the non-NaN samples
    csum = np.concatenate([np.zeros((1,) + x.shape[1:], np.intp), np.cumsum(~np.isnan(xp), axis=0)], axis=0)
    count = csum[window:window + n] - csum[:n]
    lo = np.maximum(count - 1, 0) // 2
    hi = np.maximum(count, 1) // 2
    a = np.take_along_axis(win, lo[..., None], axis=-1)[..., 0]
    b = np.take_along_axis(win, hi[..., None], axis=-1)[..., 0]
    med = (a + b) / 2.0  # odd count: lo == hi and (a + a) / 2 == a exactly
    med[count == 0] = np.nan
    return med


def median_savgol(
    positions: np.ndarray,
    rate_hz: float,
    observed: np.ndarray | None = None,
    median_window_s: float = 0.17,
    window_s: float = 0.3,
    polyorder: int = 3,
) -> np.ndarray:
    """Running median (window ``median_window_s`` s) then Savitzky-Golay (``window_s`` s).

    The median removes isolated outliers (it ignores missing samples); the
    Savitzky-Golay pass then smooths the median's staircase. Gaps longer than the
    median window are filled linearly before the second pass.
    """
    positions = np.asarray(positions, dtype=np.float64)
    obs = observed_mask(positions, observed)
    med = running_median(positions, odd_window(median_window_s, rate_hz), obs)
    return savgol(med, rate_hz, None, window_s=window_s, polyorder=polyorder)


def butterworth(
    positions: np.ndarray,
    rate_hz: float,
    observed: np.ndarray | None = None,
    cutoff_hz: float = 6.0,
    order: int = 2,
) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``(T, J, 3)`` (m) along time, cut-off ``cutoff_hz``.

    Forward-backward filtering (``sosfiltfilt``) doubles the order and has no lag, which
    is why markerless pipelines (FreeMoCap, Pose2Sim) default to it. Missing samples are
    filled linearly first; a never-observed joint stays NaN. Needs the whole take (not
    causal); a cut-off at or above Nyquist returns the filled input.
    """
    x = _filled(positions, observed)
    nyquist = 0.5 * float(rate_hz)
    if not 0 < cutoff_hz < nyquist:
        return x
    from scipy.signal import butter, sosfiltfilt  # here: importing scipy.signal is slow (savgol_coefficients)

    sos = butter(order, cutoff_hz / nyquist, btype="low", output="sos")
    n = x.shape[0]
    if n < 2:
        return x
    padlen = min(3 * (2 * len(sos) + 1), n - 1)
    return _along_time(x, lambda c: sosfiltfilt(sos, c, axis=0, padlen=padlen))


def exponential_smoothing(x: np.ndarray, alpha: float, previous: np.ndarray | None = None) -> np.ndarray:
    """Causal one-pole low-pass along axis 0: ``s(t) = s(t-1) + alpha (x(t) - s(t-1))``.

    ``previous``: ``s`` of the frame before ``x[0]`` (a stream continuing across calls);
    None starts at ``x[0]``. Splitting ``x`` into consecutive pieces, each given the last
    output of the one before, gives the same values as one call. ``alpha`` in (0, 1]: 1 =
    no smoothing; ``1 - exp(-dt / tau)`` for a time constant ``tau`` at frame period ``dt``.
    """
    x = np.asarray(x, dtype=np.float64)
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"alpha must be in (0, 1], got {alpha}")
    if len(x) == 0 or alpha == 1.0:
        return x.copy()
    start = x[0] if previous is None else np.asarray(previous, dtype=np.float64)
    from scipy.signal import lfilter  # here: importing scipy.signal is slow (savgol_coefficients)

    return lfilter([alpha], [1.0, alpha - 1.0], x, axis=0, zi=((1.0 - alpha) * start)[None])[0]


def binomial_taps(half_width: int) -> np.ndarray:
    """The ``2 h + 1`` binomial weights ``C(2h, k) / 4^h`` (they sum to 1)."""
    taps = np.array([1.0])
    for _ in range(max(0, int(half_width))):
        taps = np.convolve(taps, [0.25, 0.5, 0.25])
    return taps


def twiced_binomial_taps(half_width: int) -> np.ndarray:
    """Tukey's twicing of the binomial kernel ``B`` of half-width ``h``: ``2 B - B * B``
    (``4 h + 1`` taps; ``[-1, 4, 10, 4, -1] / 16`` for ``h = 1``).

    Its gain is ``1 - (1 - G)^2`` with ``G = cos(pi f / fs)^(2h)`` the binomial's: still
    zero at the Nyquist frequency, but the deviation from 1 is squared, so the kernel
    keeps quadratic motion exactly (a foot accelerating through a step is not smoothed
    away; the plain binomial's bias is ``h / 4`` of the second difference). At 30 Hz,
    ``h = 1``: 0.998 at 2 Hz, 0.94 at 5 Hz, 0.44 at 10 Hz.
    """
    b = binomial_taps(half_width)
    return 2.0 * np.pad(b, len(b) // 2) - np.convolve(b, b)
