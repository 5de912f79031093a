"""Measure the sensor statistics of Kinect v2 recordings (what the sensor model must reproduce).

All statistics are per joint where that matters, computed on a list of
:class:`~streamfix.motion.Motion` objects with the ``KINECT_V2`` skeleton:

``hf_sigma`` (J, 3) m
    Jitter level: robust standard deviation (1.4826 x MAD) of the positions after a
    zero-phase 4th-order Butterworth high-pass at ``HF_CUTOFF_HZ`` = 8 Hz, on runs of at
    least 32 tracked frames without a frame drop (5 frames trimmed at each run end).
    Human motion has little power above 8 Hz at 30 Hz sampling, sensor noise does; the
    MAD keeps spikes (counted separately) out of it.
``hf_band_ratio`` scalar
    Jitter colour: power of those residuals in ``HF_BANDS[0]`` (8-11.5 Hz) over
    ``HF_BANDS[1]`` (11.5 Hz-Nyquist), Hann periodogram per run, median over joints (the
    high-pass response included; a flat noise floor gives the filter's own ratio, a red
    one -- Kinect's, which smooths internally -- a larger one).
``inferred_fraction`` / ``inferred_run_mean`` (J,)
    Fraction of frames in tracking state 1 (inferred), and the mean length (frames) of
    an inferred run (runs cut by the recording's ends count as they are).
``inferred_bone_dev`` m
    How far inferred joints sit from plausible: median |l_t - l_med| over bones whose
    child is inferred and parent tracked (l_med: that bone's median tracked length).
``tracked_bone_dev`` m
    The same over bones with both ends tracked (the reference).
``drop_rate``, ``drop_mean_length``
    Sensor frames lost: a timestamp step of n median steps means n - 1 dropped frames.
``dt_jitter_s``
    Standard deviation of the timestamp step when no frame was dropped.
``bone_length`` (B,) m, ``spine_base`` (3,) m
    Median tracked bone lengths (the body the generator builds) and the median camera-space
    SpineBase position (where the generator places the subject).
``spike_rate`` (J,), ``spike_median_m``
    Outliers: tracked samples more than ``SPIKE_THRESHOLD_M`` = 3 cm from the mean of both
    neighbours and farther from it than the neighbours are from each other (a jump that
    goes and comes back), per tracked joint-frame; and their median size.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import signal

from ..motion import CONFIDENCE_INFERRED, CONFIDENCE_TRACKED, Motion
from ..skeletons import KINECT_V2

__all__ = [
    "measure_kinect",
    "hf_residual_runs",
    "HF_CUTOFF_HZ",
    "HF_SPLIT_HZ",
    "band_powers",
    "SPIKE_THRESHOLD_M",
    "MIN_RUN",
]

HF_CUTOFF_HZ = 8.0
HF_SPLIT_HZ = 11.5
SPIKE_THRESHOLD_M = 0.03
MIN_RUN = 32
TRIM = 5
MAD_TO_SIGMA = 1.4826


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the True runs of a 1-D bool array."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]))


def _drop_steps(motion: Motion) -> np.ndarray:
    """(T-1,) number of frames dropped before each frame (0 normally)."""
    dt = np.diff(motion.timestamps)
    if dt.size == 0:
        return np.zeros(0, dtype=int)
    return np.maximum(np.round(dt / np.median(dt)).astype(int) - 1, 0)


def hf_residual_runs(motion: Motion, state: float = CONFIDENCE_TRACKED) -> list[list[np.ndarray]]:
    """Per joint, the high-passed residuals (n, 3) of each of its long ``state`` runs."""
    b, a = signal.butter(4, HF_CUTOFF_HZ / (motion.rate_hz / 2.0), "high")
    drops = _drop_steps(motion)
    out = []
    for j in range(motion.n_joints):
        ok = np.isclose(motion.confidence[:, j], state) & np.isfinite(motion.positions[:, j]).all(axis=1)
        pieces = []
        for s, e in _runs(ok):
            # split the run at dropped frames: a filter over a time gap measures the gap
            cuts = [s] + [k + 1 for k in range(s, e - 1) if drops[k] > 0] + [e]
            for s2, e2 in zip(cuts[:-1], cuts[1:]):
                if e2 - s2 >= MIN_RUN:
                    r = signal.filtfilt(b, a, motion.positions[s2:e2, j], axis=0)
                    pieces.append(r[TRIM:-TRIM])
        out.append(pieces)
    return out


def band_powers(runs: list[np.ndarray], rate_hz: float) -> np.ndarray:
    """(2,) summed periodogram power of residual runs below / above ``HF_SPLIT_HZ`` (>= cut-off)."""
    p = np.zeros(2)
    for r in runs:
        f, P = signal.periodogram(r, fs=rate_hz, window="hann", axis=0)
        P = P.sum(axis=1)
        p[0] += P[(f >= HF_CUTOFF_HZ) & (f < HF_SPLIT_HZ)].mean() if ((f >= HF_CUTOFF_HZ) & (f < HF_SPLIT_HZ)).any() else 0
        p[1] += P[f >= HF_SPLIT_HZ].mean() if (f >= HF_SPLIT_HZ).any() else 0
    return p


def _robust_sigma(r: np.ndarray) -> np.ndarray:
    if len(r) < 20:
        return np.full(3, np.nan)
    return MAD_TO_SIGMA * np.median(np.abs(r - np.median(r, axis=0)), axis=0)


def spike_mask(motion: Motion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, J) spikes among tracked samples, (T, J) candidates (tracked with tracked neighbours), deviations."""
    X = motion.positions
    tr = np.isclose(motion.confidence, CONFIDENCE_TRACKED)
    T, J = tr.shape
    spikes = np.zeros((T, J), bool)
    cand = np.zeros((T, J), bool)
    dev_all = np.zeros((T, J))
    if T < 3:
        return spikes, cand, dev_all
    mid = 0.5 * (X[2:] + X[:-2])
    dev = np.linalg.norm(X[1:-1] - mid, axis=2)
    span = np.linalg.norm(X[2:] - X[:-2], axis=2)
    c = tr[1:-1] & tr[2:] & tr[:-2]
    cand[1:-1] = c
    dev_all[1:-1] = np.where(c, dev, 0.0)
    spikes[1:-1] = c & (dev > SPIKE_THRESHOLD_M) & (dev > span)
    return spikes, cand, dev_all


def _bone_devs(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    b = KINECT_V2.bone_array
    X, c = motion.positions, motion.confidence
    L = np.linalg.norm(X[:, b[:, 0]] - X[:, b[:, 1]], axis=2)
    trk = np.isclose(c, CONFIDENCE_TRACKED)
    both = trk[:, b[:, 0]] & trk[:, b[:, 1]]
    inf_child = trk[:, b[:, 0]] & np.isclose(c[:, b[:, 1]], CONFIDENCE_INFERRED)
    med = np.array([np.median(L[both[:, k], k]) if both[:, k].sum() >= 5 else np.nan for k in range(len(b))])
    d = np.abs(L - med)
    return d[both & np.isfinite(d)], d[inf_child & np.isfinite(d)]


def measure_kinect(motions: Sequence[Motion]) -> dict:
    """The sensor statistics of a set of Kinect v2 recordings (see the module doc).

    Per-joint arrays are pooled over the recordings (samples concatenated), so a joint
    tracked in only some recordings is measured where it was tracked; NaN where never.
    """
    J = KINECT_V2.n_joints
    for m in motions:
        if m.skeleton.joint_names != KINECT_V2.joint_names:
            raise ValueError(f"measure_kinect needs kinect_v2 motions, got {m.skeleton.name!r}")
    bands = np.zeros((J, 2))
    hf = [[] for _ in range(J)]
    hf_inf = [[] for _ in range(J)]
    n_frames = np.zeros(J)
    n_inf = np.zeros(J)
    n_runs = np.zeros(J)
    bone_L: list[np.ndarray] = []
    spine: list[np.ndarray] = []
    drops_total = 0
    expected_total = 0
    gap_lengths: list[int] = []
    dt_ok: list[np.ndarray] = []
    spikes = np.zeros(J)
    cands = np.zeros(J)
    spike_sizes: list[np.ndarray] = []
    dev_tr: list[np.ndarray] = []
    dev_inf: list[np.ndarray] = []
    for m in motions:
        for j, runs in enumerate(hf_residual_runs(m)):
            hf[j] += runs
            bands[j] += band_powers(runs, m.rate_hz)
        for j, runs in enumerate(hf_residual_runs(m, CONFIDENCE_INFERRED)):
            hf_inf[j] += runs
        inf = np.isclose(m.confidence, CONFIDENCE_INFERRED)
        trk = np.isclose(m.confidence, CONFIDENCE_TRACKED)
        n_frames += m.n_frames
        n_inf += inf.sum(axis=0)
        n_runs += (np.diff(np.vstack([np.zeros((1, J), bool), inf]).astype(np.int8), axis=0) == 1).sum(axis=0)
        bl = np.linalg.norm(m.positions[:, KINECT_V2.bone_array[:, 0]] - m.positions[:, KINECT_V2.bone_array[:, 1]], axis=2)
        both = trk[:, KINECT_V2.bone_array[:, 0]] & trk[:, KINECT_V2.bone_array[:, 1]]
        bone_L.append(np.where(both, bl, np.nan))
        spine.append(np.where(trk[:, :1], m.positions[:, 0], np.nan))
        steps = _drop_steps(m)
        drops_total += int(steps.sum())
        expected_total += m.n_frames + int(steps.sum())
        gap_lengths += [int(s) for s in steps if s > 0]
        dt_ok.append(np.diff(m.timestamps)[steps == 0])
        s, c, d = spike_mask(m)
        spikes += s.sum(axis=0)
        cands += c.sum(axis=0)
        spike_sizes.append(d[s])
        a, b = _bone_devs(m)
        dev_tr.append(a)
        dev_inf.append(b)
    hf_cat = [np.concatenate(h) if h else np.zeros((0, 3)) for h in hf]
    hf_inf_cat = [np.concatenate(h) if h else np.zeros((0, 3)) for h in hf_inf]
    hf_sigma = np.array([_robust_sigma(r) for r in hf_cat])
    hf_sigma_inf = np.array([_robust_sigma(r) for r in hf_inf_cat])
    ratio = np.where(bands[:, 1] > 0, bands[:, 0] / np.where(bands[:, 1] > 0, bands[:, 1], 1.0), np.nan)
    sizes = np.concatenate(spike_sizes) if spike_sizes else np.zeros(0)
    dtc = np.concatenate(dt_ok) if dt_ok else np.zeros(0)
    dtr, dinf = np.concatenate(dev_tr), np.concatenate(dev_inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "n_recordings": len(motions),
            "n_frames": int(n_frames[0]) if J else 0,
            "rate_hz": float(np.median([m.rate_hz for m in motions])),
            "hf_cutoff_hz": HF_CUTOFF_HZ,
            "hf_sigma": hf_sigma,
            "hf_samples": np.array([len(r) for r in hf_cat]),
            "hf_sigma_inferred": hf_sigma_inf,
            "hf_band_ratio": float(np.nanmedian(ratio)) if np.isfinite(ratio).any() else float("nan"),
            "inferred_fraction": n_inf / n_frames,
            "inferred_run_mean": np.where(n_runs > 0, n_inf / np.maximum(n_runs, 1), 0.0),
            "inferred_runs": n_runs,
            "bone_length": np.nanmedian(np.concatenate(bone_L), axis=0),
            "spine_base": np.nanmedian(np.concatenate(spine), axis=0),
            "inferred_bone_dev": float(np.median(dinf)) if dinf.size else float("nan"),
            "inferred_bone_dev_n": int(dinf.size),
            "tracked_bone_dev": float(np.median(dtr)) if dtr.size else float("nan"),
            "drop_rate": drops_total / max(expected_total, 1),
            "drop_mean_length": float(np.mean(gap_lengths)) if gap_lengths else 1.0,
            "dt_jitter_s": float(np.std(dtc)) if dtc.size > 1 else 0.0,
            "spike_rate": spikes / np.maximum(cands, 1),
            "spike_rate_total": float(spikes.sum() / max(cands.sum(), 1)),
            "spike_median_m": float(np.median(sizes)) if sizes.size else float("nan"),
            "spike_candidates": cands,
        }
