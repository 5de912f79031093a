"""The ``sensor`` protocol: realistic sensor errors on mocap ground truth, per error kind.

Ground truth: a BVH take (CMU, Xia) at ``rate_hz`` (30 Hz by default, a Kinect's rate)
retargeted to the Kinect v2 joints in the camera frame
(:func:`streamfix.io.retarget.bvh_to_kinect_v2` with ``to_camera=True``). For each error
kind of :mod:`streamfix.sim.sensor_errors` (at least one event each) and for ``mix`` (all
kinds at their estimated rates) and each of ``n_seeds`` seeds (``seed``, ``seed + 1``,
...), the take is corrupted once and every method cleans the same input through
:func:`streamfix.evaluation.registry.run_method`. One record per (file, kind, seed, method)::

    {file, rate_hz, protocol: "sensor", level: 0, kind, seed, method, n_frames, n_joints,
     n_corrupted, n_clean,                 # joint-frames the kind changed / left exact
     err_m, err_corrupted_m, err_clean_m,  # mean joint error (m) on all / those / these
     unfilled,                             # fraction of joint-frames the method left NaN
     aje_m (= err_m), abe_m, jitter,       # m, m, m/frame^2
     seam_d2, other_d2, seam_ratio,        # jitter next to engine window hand-overs vs rest
     time_s}

``err_clean_m`` is collateral damage: what a method does to joint-frames the sensor got
right (in ``mix``, those with noise only; None for ``noise`` alone, which touches all).
An error is None where the method left any of its joint-frames NaN (``input`` on
``dropout``): a partial mean would not compare; ``unfilled`` says how many it left. The seam
frames are the two around each window hand-over of the schedule the method ran
(:func:`streamfix.evaluation.registry.handover_frames`: where the engine's blend passes a
frame to the newer window; ``serve``'s schedule for methods without windows, so the
baselines show what no seam looks like), against the other frames within one hop
(:func:`streamfix.core.metrics.seam_sums`).
:func:`summarise` pools records over files and seeds (joint-frame weighted).
"""
from __future__ import annotations

import inspect
import time
import warnings
import zlib
from collections import defaultdict
from pathlib import Path

import numpy as np

from ..core import metrics
from ..motion import Motion
from ..sim.sensor_errors import KINDS, MIX_KINDS, apply_sensor_errors
from ..skeletons import KINECT_V2
from .registry import METHODS, engine_config, handover_frames, is_kinect_file, load_motion, run_method

__all__ = [
    "run_sensor",
    "PROTOCOLS",
    "DEFAULT_METHODS",
    "SCORED_KINDS",
    "DEFAULT_RATE_HZ",
    "N_SEEDS",
    "ground_truth",
    "handover_frames",
    "summarise",
    "format_table",
]

DEFAULT_METHODS = ("input", "median_savgol", "savgol", "one_euro", "one_euro_tuned", "holt", "butterworth",
                   "linear", "streamfix", "streamfix_serve", "streamfix_live")
DEFAULT_RATE_HZ = 30.0
N_SEEDS = 3
_MIX = "mix"
SCORED_KINDS = KINDS + (_MIX,)


def ground_truth(path: str | Path, rate_hz: float = DEFAULT_RATE_HZ) -> Motion:
    """A take as complete Kinect v2 joints in the camera frame at ``rate_hz``."""
    from ..io.retarget import bvh_to_kinect_v2

    if is_kinect_file(path):
        raise ValueError(f"{path}: the sensor protocol corrupts ground truth (optical mocap such as a BVH take); "
                         f"a Kinect recording already carries sensor errors (use --protocol kinect)")
    motion = load_motion(path, rate_hz)
    if motion.skeleton.joint_names != KINECT_V2.joint_names:
        motion = bvh_to_kinect_v2(motion, to_camera=True)
    if not motion.observed.all():
        raise ValueError(
            f"{path}: the sensor protocol needs complete ground truth (optical mocap such as a BVH take), "
            f"{int((~motion.observed).sum())} of {motion.observed.size} joint-frames are missing"
        )
    return motion


def _rng(seed: int, kind: str, path: str | Path) -> np.random.Generator:
    """One fixed stream per (seed, kind, file name): every method sees the same input."""
    return np.random.default_rng([int(seed), zlib.crc32(f"sensor:{kind}:{Path(path).name}".encode())])


def _available(methods) -> list[str]:
    out = []
    for name in methods:
        if name in METHODS:
            out.append(name)
        else:
            warnings.warn(f"sensor protocol: method {name!r} is not in this registry; skipped", stacklevel=3)
    return out


_PASSES_SKELETON = "skeleton" in inspect.signature(run_method).parameters


def _mean(err: np.ndarray, mask: np.ndarray) -> float | None:
    """Mean over ``mask``; None if empty or if the method left any of it NaN (not comparable)."""
    v = err[mask]
    if not v.size or not np.isfinite(v).all():
        return None
    return float(v.mean())


def _score(pred: np.ndarray, truth: np.ndarray, corrupted: np.ndarray, seam: tuple[np.ndarray, int],
           bones: np.ndarray) -> dict:
    err = metrics.joint_errors(pred, truth)
    all_ = np.ones_like(corrupted)
    seam_d2, other_d2 = metrics.seam_jitter(pred, *seam)
    return {
        "err_m": _mean(err, all_),
        "err_corrupted_m": _mean(err, corrupted),
        "err_clean_m": _mean(err, ~corrupted),
        "unfilled": float((~np.isfinite(pred).all(axis=2)).mean()),
        "aje_m": _mean(err, all_),
        "abe_m": metrics.abe(pred, truth, bones),
        "jitter": metrics.jitter(pred),
        "seam_d2": seam_d2,
        "other_d2": other_d2,
        "seam_ratio": seam_d2 / other_d2 if other_d2 > 0 else None,
    }


def run_sensor(paths, *, rate_hz=None, levels=None, seed=0, methods=None, kinds=None, n_seeds=N_SEEDS) -> list[dict]:
    """Score methods on realistic sensor errors (see the module doc); ``levels`` is ignored."""
    rate = float(rate_hz) if rate_hz is not None else DEFAULT_RATE_HZ
    names = _available(methods if methods else DEFAULT_METHODS)
    kinds = list(kinds) if kinds else list(SCORED_KINDS)
    unknown = [k for k in kinds if k not in SCORED_KINDS]
    if unknown:
        raise ValueError(f"unknown sensor error kind(s) {', '.join(unknown)}; expected some of: {', '.join(SCORED_KINDS)}")
    if int(n_seeds) < 1:
        raise ValueError(f"n_seeds must be >= 1, got {n_seeds}")
    extra = {"skeleton": KINECT_V2} if _PASSES_SKELETON else {}
    bones = KINECT_V2.bone_array
    records: list[dict] = []
    for path in paths:
        truth_motion = ground_truth(path, rate)
        truth = truth_motion.positions
        T, J, _ = truth.shape
        if T < 3:
            raise ValueError(f"{path}: the sensor protocol needs at least 3 frames at {rate:g} Hz, got {T}")
        schedules = {name: engine_config(name, rate) for name in names}
        seams = {name: (cfg.handover_frames(T), cfg.hop) for name, cfg in schedules.items()}  # frames, local radius
        for kind in kinds:
            for s in range(int(seed), int(seed) + int(n_seeds)):
                rng = _rng(s, kind, path)
                if kind == _MIX:
                    c = apply_sensor_errors(truth, rng, MIX_KINDS, rate_hz=rate)
                else:
                    c = apply_sensor_errors(truth, rng, [kind], rate_hz=rate, min_events=1)
                corrupted = c.corrupted
                for name in names:
                    t0 = time.perf_counter()
                    pred = run_method(name, c.positions, c.confidence, bones, rate, **extra)
                    dt = time.perf_counter() - t0
                    records.append({
                        "file": str(path),
                        "rate_hz": rate,
                        "protocol": "sensor",
                        "level": 0.0,
                        "kind": kind,
                        "seed": s,
                        "method": name,
                        "n_frames": T,
                        "n_joints": J,
                        "n_corrupted": int(corrupted.sum()),
                        "n_clean": int((~corrupted).sum()),
                        **_score(pred, truth, corrupted, seams[name], bones),
                        "time_s": dt,
                    })
    return records


# ------------------------------------------------------------------------- summaries
_POOLED = (("err_m", "n_all"), ("err_corrupted_m", "n_corrupted"), ("err_clean_m", "n_clean"),
           ("unfilled", "n_all"), ("seam_d2", None), ("other_d2", None))


def summarise(records: list[dict]) -> dict[str, dict[str, dict]]:
    """``{kind: {method: pooled metrics}}`` over files and seeds.

    Errors are weighted by the joint-frames they were measured on (``n_corrupted``,
    ``n_clean``, all); ``seam_ratio`` is the ratio of the pooled seam and other jitters.
    """
    acc: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(float)))
    for r in records:
        if r.get("protocol") != "sensor":
            continue
        a = acc[r["kind"]][r["method"]]
        n = {"n_all": r["n_frames"] * r["n_joints"], "n_corrupted": r["n_corrupted"], "n_clean": r["n_clean"]}
        for key, weight in _POOLED:
            v = r.get(key)
            if v is None or not np.isfinite(v):
                continue
            w = float(n[weight]) if weight else 1.0
            a[key] += w * v
            a[key + ":w"] += w
        a["time_s"] += r.get("time_s", 0.0)
        a["records"] += 1
    out: dict[str, dict[str, dict]] = {}
    for kind, per in acc.items():
        out[kind] = {}
        for method, a in per.items():
            m = {key: (a[key] / a[key + ":w"] if a[key + ":w"] > 0 else None) for key, _ in _POOLED}
            m["seam_ratio"] = m["seam_d2"] / m["other_d2"] if m["seam_d2"] and m["other_d2"] else None
            m["time_s"] = a["time_s"]
            m["records"] = int(a["records"])
            out[kind][method] = m
    return out


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1000:.1f}"


def format_table(records: list[dict]) -> str:
    """Per kind (rows) and method (columns): mean joint error in mm on all / corrupted /
    clean joint-frames, pooled over files and seeds; then the seam ratio per method."""
    summary = summarise(records)
    methods = list(dict.fromkeys(r["method"] for r in records if r.get("protocol") == "sensor"))
    kinds = [k for k in SCORED_KINDS if k in summary]
    w = max([15] + [len(m) + 2 for m in methods])  # a column fits its method's name ("streamfix_serve")
    lines = []
    for key, title in (("err_m", "all joint-frames"), ("err_corrupted_m", "corrupted joint-frames"),
                       ("err_clean_m", "uncorrupted joint-frames (collateral damage)")):
        lines.append(f"mean joint error, mm, {title}")
        lines.append(f"{'kind':<9}" + "".join(f"{m:>{w}}" for m in methods))
        for kind in kinds:
            lines.append(f"{kind:<9}" + "".join(f"{_mm(summary[kind].get(m, {}).get(key)):>{w}}" for m in methods))
        lines.append("")
    seam = {m: summarise([dict(r, kind="all") for r in records if r.get("protocol") == "sensor"])["all"][m]["seam_ratio"]
            for m in methods}
    lines.append("seam ratio (jitter next to window hand-overs / within a hop of them), all kinds")
    lines.append(" " * 9 + "".join(f"{m:>{w}}" for m in methods))
    lines.append(" " * 9 + "".join(f"{'-' if seam[m] is None else f'{seam[m]:.3f}':>{w}}" for m in methods))
    return "\n".join(lines)


PROTOCOLS = {"sensor": run_sensor}
