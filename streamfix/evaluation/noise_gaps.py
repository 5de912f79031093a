"""Yang et al. 2019 protocol on ground-truth motion: noise (Section IV-B) and gaps.

``noise``: uniform noise in [-0.25, 0.25] m on ``level`` % of the scalar entries of D.
``gaps``: random joints missing for runs of 10-60 frames until ``level`` % of the
joint-frames are missing. Each (file, level) draws from its own fixed seed, so every
method sees the identical corrupted input. Records (one per file x level x method)::

    {file, rate_hz, protocol, level, method, n_frames, n_joints, aje_m, abe_m,
     jitter (m/frame^2), gap_mae_m (gaps only, else None), time_s}
"""
from __future__ import annotations

import time
import zlib
from pathlib import Path
from typing import Iterable

import numpy as np

from ..core import metrics
from ..core.corruption import add_noise, apply_gaps, gap_mask
from .registry import METHODS, load_motion, run_method

__all__ = ["run_noise", "run_gaps", "PROTOCOLS", "DEFAULT_LEVELS", "evaluate_clip"]

DEFAULT_LEVELS = {"noise": (5, 10, 15, 20, 80), "gaps": (10, 20)}


def _rng(seed: int, protocol: str, level: float, name: str) -> np.random.Generator:
    """One fixed stream per (seed, protocol, level, file name)."""
    key = zlib.crc32(f"{protocol}:{level:g}:{Path(name).name}".encode())
    return np.random.default_rng([int(seed), key])


def evaluate_clip(
    truth: np.ndarray,
    corrupted: np.ndarray,
    observed: np.ndarray,
    bones: np.ndarray,
    rate_hz: float,
    methods: Iterable[str],
    missing: np.ndarray | None = None,
    skeleton=None,
) -> list[dict]:
    """Score each method on one corrupted clip; ``missing`` ``(T,J)`` enables gap_mae."""
    conf = observed.astype(np.float64)
    out = []
    for name in methods:
        t0 = time.perf_counter()
        pred = run_method(name, corrupted, conf, bones, rate_hz, skeleton=skeleton)
        dt = time.perf_counter() - t0
        rec = {
            "method": name,
            "aje_m": metrics.aje(pred, truth),
            "abe_m": metrics.abe(pred, truth, bones),
            "jitter": metrics.jitter(pred),
            "gap_mae_m": metrics.gap_mae(pred, truth, missing) if missing is not None else None,
            "time_s": dt,
        }
        out.append(rec)
    return out


def _run(protocol: str, paths, rate_hz, levels, seed, methods) -> list[dict]:
    methods = list(methods or METHODS)  # the methods these protocols run (not other protocols')
    levels = list(levels or DEFAULT_LEVELS[protocol])
    records: list[dict] = []
    for path in paths:
        motion = load_motion(path, rate_hz)
        truth = np.asarray(motion.positions, dtype=np.float64)
        if not motion.observed.all():
            raise ValueError(
                f"{path}: the {protocol} protocol needs complete ground truth, "
                f"{int((~motion.observed).sum())} joint-frames are missing"
            )
        bones = motion.skeleton.bone_array
        n_frames, n_joints, _ = truth.shape
        for level in levels:
            rng = _rng(seed, protocol, level, str(path))
            if protocol == "noise":
                corrupted, _ = add_noise(truth, level / 100.0, rng)
                observed = np.ones((n_frames, n_joints), dtype=bool)
                missing = None
            else:
                missing = gap_mask(n_frames, n_joints, level / 100.0, rng)
                corrupted, observed = apply_gaps(truth, missing)
            for rec in evaluate_clip(truth, corrupted, observed, bones, motion.rate_hz, methods, missing, motion.skeleton):
                records.append({
                    "file": str(path),
                    "rate_hz": motion.rate_hz,
                    "protocol": protocol,
                    "level": float(level),
                    "n_frames": n_frames,
                    "n_joints": n_joints,
                    **rec,
                })
    return records


def run_noise(paths, *, rate_hz=None, levels=None, seed=0, methods=None) -> list[dict]:
    """Noise protocol on ground-truth files (BVH/C3D); see the module doc."""
    return _run("noise", paths, rate_hz, levels, seed, methods)


def run_gaps(paths, *, rate_hz=None, levels=None, seed=0, methods=None) -> list[dict]:
    """Gap protocol on ground-truth files; records carry gap_mae_m."""
    return _run("gaps", paths, rate_hz, levels, seed, methods)


PROTOCOLS = {"noise": run_noise, "gaps": run_gaps}
