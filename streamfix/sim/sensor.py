"""A Kinect v2 sensor model whose parameters come from :func:`streamfix.sim.measure.measure_kinect`.

:meth:`SensorModel.apply` turns a clean ``KINECT_V2`` motion (sampled at the model's
rate) into what the sensor would have reported:

1. **tracking state** per joint: a two-state Markov chain (tracked <-> inferred) with
   leave probability ``1 / inferred_run_mean`` and enter probability chosen so the
   stationary inferred fraction is ``inferred_fraction`` (both measured per joint);
2. **jitter**: AR(1) Gaussian noise per joint and axis, ``n_t = rho n_{t-1} +
   sqrt(1 - rho^2) sigma e_t``; ``rho`` is fitted so the 8 Hz high-passed noise has the
   measured spectral colour ``hf_band_ratio``, ``sigma`` so its robust level equals the measured
   ``hf_sigma`` (the fraction of AR(1) power above the cut-off is computed from the
   filter's response). Inferred samples use the inferred level where it was measured;
3. **inferred offset**: an inferred joint sits off its true place by an Ornstein-Uhlenbeck
   bias (per axis std ``sigma_b = inferred_bone_dev / 0.6745``, so that the median
   |bone-length error| of a bone whose child is inferred matches the measurement);
4. **outliers**: on tracked samples, a jump of ``threshold + Exp(mean)`` metres in a
   random direction, the mean chosen so the median jump equals the measured median; the
   per-joint rate is the measured one minus the rate at which the jitter alone already
   passes the spike test (found by a fixed-seed Monte Carlo of the AR(1) noise), so that
   measuring the output gives back the measured rate;
5. **dropped frames**: each frame independently lost with the measured drop rate (the
   real recordings' gaps are all single frames), and **timestamp jitter** with the
   measured step standard deviation (``/ sqrt(2)`` per timestamp).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import signal

from ..motion import CONFIDENCE_INFERRED, CONFIDENCE_TRACKED, Motion
from ..skeletons import KINECT_V2
from .measure import HF_CUTOFF_HZ, HF_SPLIT_HZ, SPIKE_THRESHOLD_M

__all__ = ["SensorModel", "ar1_hf_properties", "fit_ar1", "noise_spike_rate", "RHO_MAX"]

_J = KINECT_V2.n_joints
_MIN_HF_SAMPLES = 100
_MIN_SPIKE_CANDIDATES = 200


def ar1_hf_properties(rho: float, rate_hz: float) -> tuple[float, float]:
    """(variance fraction above the cut-off, ``hf_band_ratio``) of unit-variance AR(1) noise.

    Uses the zero-phase Butterworth high-pass of :mod:`streamfix.sim.measure` (power
    response |H|^4 for filtfilt) on the AR(1) spectrum (1 - rho^2) / |1 - rho e^{-iw}|^2.
    """
    b, a = signal.butter(4, HF_CUTOFF_HZ / (rate_hz / 2.0), "high")
    w, h = signal.freqz(b, a, worN=4096)
    f = w / np.pi * rate_hz / 2.0
    S = (1 - rho**2) / (1 - 2 * rho * np.cos(w) + rho**2)
    P = S * np.abs(h) ** 4
    lo = P[(f >= HF_CUTOFF_HZ) & (f < HF_SPLIT_HZ)].mean()
    hi = P[f >= HF_SPLIT_HZ].mean()
    return float(P.mean()), float(lo / hi)


RHO_MAX = 0.6


def fit_ar1(band_ratio: float, rate_hz: float) -> float:
    """The AR(1) coefficient whose high-passed noise has ``hf_band_ratio``, in [-0.9, RHO_MAX].

    Capped at ``RHO_MAX``: above it the band ratio hardly changes (1.01 at 0.5, 1.05 at
    0.9 for 30 Hz) while the implied full-band noise grows fivefold, so 8-15 Hz data
    cannot pin it down; the cap keeps the low-frequency extrapolation conservative.
    """
    if not np.isfinite(band_ratio):
        return 0.0
    grid = np.linspace(-0.9, RHO_MAX, 301)
    vals = np.array([ar1_hf_properties(r, rate_hz)[1] for r in grid])
    return float(grid[np.argmin(np.abs(np.log(vals) - np.log(band_ratio)))])


def noise_spike_rate(sigma: np.ndarray, rho: float, n: int = 20000, seed: int = 0) -> np.ndarray:
    """(J,) rate at which AR(1) jitter of per-axis ``sigma`` (J, 3) alone passes the spike test."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((n + 100, len(sigma), 3))
    x = signal.lfilter([np.sqrt(1 - rho**2)], [1.0, -rho], e, axis=0)[100:] * sigma
    dev = np.linalg.norm(x[1:-1] - 0.5 * (x[2:] + x[:-2]), axis=2)
    span = np.linalg.norm(x[2:] - x[:-2], axis=2)
    return ((dev > SPIKE_THRESHOLD_M) & (dev > span)).mean(axis=0)


def _fill(a: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    bad = ~np.isfinite(a)
    a[bad] = np.broadcast_to(fallback, a.shape)[bad]
    return a


@dataclass
class SensorModel:
    """Kinect v2 sensor parameters (SI units; per-joint arrays in KINECT_V2 order)."""

    rate_hz: float
    noise_sigma: np.ndarray  # (J, 3) m, full-band AR(1) std
    noise_rho: float
    inferred_noise_sigma: np.ndarray  # (J, 3) m
    inferred_fraction: np.ndarray  # (J,)
    inferred_run_mean: np.ndarray  # (J,) frames
    inferred_bias_sigma: float  # m per axis
    inferred_bias_tau_s: float
    spike_rate: np.ndarray  # (J,) per tracked joint-frame
    spike_excess_mean_m: float
    drop_rate: float
    dt_jitter_s: float
    spike_threshold_m: float = SPIKE_THRESHOLD_M
    source: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("noise_sigma", "inferred_noise_sigma"):
            setattr(self, name, np.broadcast_to(np.asarray(getattr(self, name), dtype=np.float64), (_J, 3)).copy())
        for name in ("inferred_fraction", "inferred_run_mean", "spike_rate"):
            setattr(self, name, np.broadcast_to(np.asarray(getattr(self, name), dtype=np.float64), (_J,)).copy())

    @classmethod
    def from_measurements(cls, profile: dict, pooled: dict | None = None, *, bias_tau_s: float = 1.0) -> "SensorModel":
        """Build from ``measure_kinect`` output for one profile (e.g. seated), falling back to
        ``pooled`` (all recordings) for joints the profile never tracked long enough. Drop
        rate, timestamp jitter, jitter colour and outlier rates are sensor properties and
        come from ``pooled`` when given; outlier rates from the profile where it has at
        least 200 tracked joint-frames of a joint, else from ``pooled``."""
        pooled = pooled or profile
        rate = float(profile["rate_hz"])
        rho = fit_ar1(pooled["hf_band_ratio"], rate)
        frac, _ = ar1_hf_properties(rho, rate)
        hf = np.array(profile["hf_sigma"], dtype=np.float64)
        hf[np.asarray(profile["hf_samples"]) < _MIN_HF_SAMPLES] = np.nan
        hf = _fill(hf, np.asarray(pooled["hf_sigma"]))
        hf = _fill(hf, np.nanmedian(hf, axis=0))
        sigma = hf / np.sqrt(frac)
        hf_inf = _fill(np.asarray(profile["hf_sigma_inferred"]), np.asarray(pooled["hf_sigma_inferred"]))
        inf_sigma = _fill(hf_inf / np.sqrt(frac), sigma)
        spike_median = float(pooled["spike_median_m"])
        excess = max(spike_median - SPIKE_THRESHOLD_M, 1e-3) / np.log(2.0) if np.isfinite(spike_median) else 0.01
        spike_rate = np.where(
            np.asarray(profile["spike_candidates"]) >= _MIN_SPIKE_CANDIDATES,
            np.asarray(profile["spike_rate"], dtype=np.float64),
            np.asarray(pooled["spike_rate"], dtype=np.float64),
        )
        dev = float(profile["inferred_bone_dev"])
        if not np.isfinite(dev):
            dev = float(pooled["inferred_bone_dev"])
        return cls(
            rate_hz=rate,
            noise_sigma=sigma,
            noise_rho=rho,
            inferred_noise_sigma=inf_sigma,
            inferred_fraction=np.asarray(profile["inferred_fraction"], dtype=np.float64),
            inferred_run_mean=np.asarray(profile["inferred_run_mean"], dtype=np.float64),
            inferred_bias_sigma=dev / 0.6745,
            inferred_bias_tau_s=bias_tau_s,
            spike_rate=np.clip(spike_rate - noise_spike_rate(sigma, rho), 0.0, 1.0),
            spike_excess_mean_m=float(excess),
            drop_rate=float(pooled["drop_rate"]),
            dt_jitter_s=float(pooled["dt_jitter_s"]),
        )

    def to_dict(self) -> dict:
        """Plain-data form (lists), for printing and README tables."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}

    # ------------------------------------------------------------------ simulation
    def tracking_states(self, n_frames: int, rng: np.random.Generator) -> np.ndarray:
        """(T, J) bool, True = inferred: the per-joint two-state Markov chain."""
        f = np.clip(self.inferred_fraction, 0.0, 1.0)
        run = np.maximum(self.inferred_run_mean, 1.0)
        p_exit = np.where(f > 0, 1.0 / run, 1.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            p_enter = np.where(f >= 1.0, 1.0, np.clip(p_exit * f / np.maximum(1.0 - f, 1e-12), 0.0, 1.0))
        p_enter = np.where(f > 0, p_enter, 0.0)
        u = rng.random((n_frames, _J))
        state = np.zeros((n_frames, _J), bool)
        cur = rng.random(_J) < f
        for t in range(n_frames):  # recursive: loops over frames, vectorised over joints
            state[t] = cur
            cur = np.where(cur, u[t] >= p_exit, u[t] < p_enter)
        return state

    def _ar1(self, shape: tuple, rho: float, rng: np.random.Generator, burn: int = 100) -> np.ndarray:
        e = rng.standard_normal((shape[0] + burn,) + shape[1:])
        return signal.lfilter([np.sqrt(1 - rho**2)], [1.0, -rho], e, axis=0)[burn:]

    def apply(self, clean: Motion, seed: int | np.random.Generator = 0) -> Motion:
        """The sensor's view of ``clean`` (a KINECT_V2 motion at ``rate_hz``)."""
        if clean.skeleton.joint_names != KINECT_V2.joint_names:
            raise ValueError(f"the Kinect v2 sensor model needs kinect_v2 motions, got {clean.skeleton.name!r}")
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        T = clean.n_frames
        X = clean.positions.copy()
        inferred = self.tracking_states(T, rng)
        unit = self._ar1((T, _J, 3), self.noise_rho, rng)
        sigma = np.where(inferred[:, :, None], self.inferred_noise_sigma, self.noise_sigma)
        X += unit * sigma
        rho_b = float(np.exp(-1.0 / (self.inferred_bias_tau_s * self.rate_hz)))
        bias = self._ar1((T, _J, 3), rho_b, rng, burn=int(5 * self.inferred_bias_tau_s * self.rate_hz) + 1)
        X += np.where(inferred[:, :, None], self.inferred_bias_sigma * bias, 0.0)
        spikes = (rng.random((T, _J)) < self.spike_rate) & ~inferred
        spikes[[0, -1]] = False
        n_sp = int(spikes.sum())
        d = rng.standard_normal((n_sp, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        X[spikes] += d * (self.spike_threshold_m + rng.exponential(self.spike_excess_mean_m, n_sp))[:, None]
        keep = rng.random(T) >= self.drop_rate
        keep[[0, -1]] = True
        ts = clean.timestamps + rng.normal(0.0, self.dt_jitter_s / np.sqrt(2.0), T)
        ts = np.maximum.accumulate(ts)  # jitter is ~1 % of a step: never reorders in practice
        conf = np.where(inferred, CONFIDENCE_INFERRED, CONFIDENCE_TRACKED)
        conf = np.where(clean.observed, conf, 0.0)
        meta = {"sensor_model": "kinect_v2", "dropped_frames": int((~keep).sum()), "spikes": n_sp}
        return Motion(X[keep], conf[keep], ts[keep], self.rate_hz, KINECT_V2, meta=meta)
