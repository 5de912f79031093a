"""Li et al. (2020) protocol: long marker gaps and whole-frame blackouts (Tables 1-2, Fig. 8).

``long-gaps`` on complete ground-truth takes (C3D/BVH): gaps in distinct, randomly
chosen (seeded) joints, evenly spaced in time over the take:

* gap length sweep (Table 1): 5 gaps of 20, 50, 80, 100 frames;
* gap count sweep (Table 2): 1, 2, 3, 5, 8 gaps of 100 frames.

``levels`` given -> each level is a gap length (frames) with 5 gaps. ``level`` in the
records is the missing rate (% of joint samples). Takes with real gaps (e.g.
03_rolling.c3d) have no ground truth: each method fills them and the record carries
``plausibility`` (fraction of filled samples whose rigid marker pairs stay in the
distance range observed where both markers are visible) instead of an error.

``blackout``: windows of 200 frames (the paper's segments, scaled with the rate)
evenly spread over the take, the middle ``level`` % of a window's frames removed
whole (levels 5-30 %); one record per (file, level, method), errors averaged over
the windows.

Training data for ``pca``: the corrupted take itself (its observed samples only, so
never the gap); ``pca-ref`` adds the other ground-truth takes of the run that have
the same marker/joint names (reference takes of other subjects: on 85_02 trained
with 135_02 this is worse than the take alone). Blackouts train on the take
outside the test window (plus the other takes for ``pca-ref``). Errors: ``gap_mae_m`` is Eq. (17)/(18): the per-gap mean of
``|m_hat(n) - m(n)|`` averaged over gaps, in metres (x1000 for the paper's mm).

Methods (``methods=None`` = all available): ``pca`` (local templates, boundary
correction; :func:`streamfix.core.pca_fill.pca_fill`), ``pca-global`` (the paper's
whole-frame template, no boundary correction: Eq. (4) as printed), ``linear``,
``spline`` (:mod:`streamfix.core.interpolate`), ``gapfill-rbt``, ``gapfill-pattern``,
``gapfill-spline`` (PyPI ``gapfill``: rigid-body fill from the 3 most rigid partner
markers, donor-pattern fill from the most rigid partner, spline; samples a
``gapfill`` function leaves empty are interpolated linearly), ``alm`` (Yang et al.
Algorithm 1 via :func:`streamfix.core.alm.solve` with the mask, on a window of
``ALM_CONTEXT`` frames around each gap / blackout), ``streamfix`` (what ``streamfix clean``
writes: :func:`streamfix.cleaning.clean_recording`, the gap filler where it applies, then the
streaming engine on the file schedule) and ``streamfix_serve`` (the engine on ``serve``'s
schedule: what its ``clean`` topic publishes), each run on the frames from
``ENGINE_CONTEXT_S`` before the first gap to as long after the last (the engine's windows are
local; farther frames would only add their cost).
"""
from __future__ import annotations

import time
import types
import zlib
from pathlib import Path

import numpy as np

from ..core import metrics
from ..core import pca_gapfill as pg
from ..core.pca_fill import pca_fill
from ..core.interpolate import interpolate_linear, interpolate_spline
from .registry import load_motion

__all__ = ["run_long_gaps", "run_blackout", "PROTOCOLS", "METHODS", "gap_configs", "make_gaps", "eq17_mae"]

LENGTH_SWEEP = (20, 50, 80, 100)
COUNT_SWEEP = (1, 2, 3, 5, 8)
BLACKOUT_LEVELS = (5, 10, 15, 20, 25, 30)
BLACKOUT_WINDOW_S = 200 / 120.0
BLACKOUT_WINDOWS = 6
ALM_CONTEXT = 150
METHODS = ("pca", "pca-ref", "pca-global", "linear", "spline", "gapfill-rbt", "gapfill-pattern", "gapfill-spline", "alm",
           "streamfix", "streamfix_serve")
ENGINE_CONTEXT_S = 4.0


def _rng(seed: int, protocol: str, key: str, name: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(f"{protocol}:{key}:{Path(name).name}".encode())])


def gap_configs(levels) -> list[tuple[int, int]]:
    """``(gap_count, gap_frames)`` pairs: the paper's two sweeps, or 5 gaps per level."""
    if levels:
        return [(5, int(round(float(lv)))) for lv in levels]
    return [(5, L) for L in LENGTH_SWEEP] + [(n, 100) for n in COUNT_SWEEP if n != 5]


def make_gaps(n_frames: int, n_joints: int, count: int, length: int, rng: np.random.Generator
              ) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """``count`` gaps of ``length`` frames in distinct joints, evenly spaced in time.

    Returns the missing mask ``(T, J)`` and the gaps as ``(joint, start, stop)``.
    Gap starts are spread evenly over ``[1, T - length - 1]`` (an observed frame on
    both sides, as in the paper's template).
    """
    length = int(min(length, n_frames - 2))
    starts = np.linspace(1, n_frames - length - 1, count + 2)[1:-1].astype(int) if count > 1 else \
        np.array([(n_frames - length) // 2])
    joints = rng.choice(n_joints, size=min(count, n_joints), replace=False)
    miss = np.zeros((n_frames, n_joints), dtype=bool)
    gaps = []
    for j, s in zip(joints, starts):
        miss[s:s + length, j] = True
        gaps.append((int(j), int(s), int(s + length)))
    return miss, gaps


def eq17_mae(pred: np.ndarray, truth: np.ndarray, gaps: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Eq. (17): mean over gaps of the per-gap mean error; ``gaps`` = (frames, joints) index arrays (m)."""
    errs = [float(np.mean(np.linalg.norm(pred[f, j] - truth[f, j], axis=-1))) for f, j in gaps]
    return float(np.mean(errs)) if errs else float("nan")


# --------------------------------------------------------------------------- methods
def _gapfill_module():
    try:
        import gapfill.gapfill as gf
    except ImportError:
        return None
    if not hasattr(gf.np, "int"):  # gapfill 0.0.7 calls np.int (removed in numpy 1.24)
        shim = types.ModuleType("numpy_int_shim")
        shim.__dict__.update(np.__dict__)
        shim.int = int
        gf.np = shim
    return gf


def _gapfill(kind: str):
    def run(x, obs, ctx):
        gf = _gapfill_module()
        if gf is None:
            raise RuntimeError("the PyPI package 'gapfill' is not installed")
        out = x.copy()
        out[~obs] = np.nan
        rank = ctx["partners"]
        for j in np.flatnonzero((~obs).any(axis=0)):  # per marker, as the package works
            tgt = out[:, j].copy()
            if kind == "rbt":
                gf.fill_marker_gap_rbt(tgt, np.stack([x[:, k] for k in rank[j][:3]]))
            elif kind == "pattern":
                gf.fill_marker_gap_pattern2(tgt, x[:, rank[j][0]].copy())
            else:
                gf.fill_marker_gap_interp(tgt)
            out[:, j] = tgt
        left = ~np.isfinite(out).all(axis=2)
        if left.any():
            out = interpolate_linear(out, ~left)[0]
        return out
    return run


def _pca(global_template: bool, with_refs: bool = False):
    def run(x, obs, ctx):
        kw = dict(n_partners=None, boundary_correction=False) if global_template else {}
        ts = ctx["training_ref"] if with_refs else ctx["training"]
        return pca_fill(x, obs, ts, blackout_window=ctx["window"], **kw)[0]
    return run


def _alm(x, obs, ctx):
    from ..core.alm import SolverParams, solve

    out = interpolate_linear(x, obs)[0]
    T_len = x.shape[0]
    rows = np.flatnonzero((~obs).any(axis=1))
    # windows of ALM_CONTEXT frames of context around each run of frames with gaps
    d = np.diff(rows)
    cuts = np.flatnonzero(d > 2 * ALM_CONTEXT) + 1
    for grp in np.split(rows, cuts):
        a, b = max(grp[0] - ALM_CONTEXT, 0), min(grp[-1] + ALM_CONTEXT + 1, T_len)
        seg = np.where(obs[a:b, :, None], x[a:b], np.nan)
        res = solve(seg, obs[a:b], np.zeros((0, 2), dtype=np.intp), None, SolverParams(mode="yang"))
        est = res.positions
        m = ~obs[a:b]
        out[a:b][m] = est[m]
    return out


def _engine(serve: bool):
    def run(x, obs, ctx):
        T_len = x.shape[0]
        rows = np.flatnonzero((~obs).any(axis=1))
        out = np.where(obs[..., None], x, np.nan)
        if not len(rows):
            return out
        pad = int(round(ENGINE_CONTEXT_S * ctx["rate_hz"]))
        a, b = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, T_len)
        sk, rate = ctx["skeleton"], float(ctx["rate_hz"])
        if serve:
            from .registry import run_method

            out[a:b] = run_method("streamfix_serve", out[a:b], obs[a:b].astype(np.float64), sk.bone_array, rate,
                                  skeleton=sk)
        else:
            from ..cleaning import clean_recording
            from ..motion import Motion

            seg = Motion(out[a:b], obs[a:b].astype(np.float64), np.arange(b - a) / rate, rate, sk)
            out[a:b] = clean_recording(seg).motion.positions
        return out
    return run


_METHOD_FUNCS = {
    "pca": _pca(False),
    "pca-ref": _pca(False, True),
    "pca-global": _pca(True),
    "linear": lambda x, obs, ctx: interpolate_linear(x, obs)[0],
    "spline": lambda x, obs, ctx: interpolate_spline(x, obs)[0],
    "gapfill-rbt": _gapfill("rbt"),
    "gapfill-pattern": _gapfill("pattern"),
    "gapfill-spline": _gapfill("spline"),
    "alm": _alm,
    "streamfix": _engine(serve=False),
    "streamfix_serve": _engine(serve=True),
}


def _available(methods) -> list[str]:
    names = list(methods or METHODS)
    for n in names:
        if n not in _METHOD_FUNCS:
            raise ValueError(f"unknown long-gaps method {n!r}; expected one of: {', '.join(METHODS)}")
    if methods is None and _gapfill_module() is None:
        names = [n for n in names if not n.startswith("gapfill")]
    return names


def _run_method(name, x, obs, ctx) -> tuple[np.ndarray, float]:
    t0 = time.perf_counter()
    xin = np.where(obs[..., None], x, np.nan)
    pred = np.asarray(_METHOD_FUNCS[name](xin, obs, ctx), dtype=np.float64)
    pred[obs] = x[obs]                                       # no method may touch observed data
    return pred, time.perf_counter() - t0


# --------------------------------------------------------------------------- data
def _load(paths, rate_hz):
    motions = [(str(p), load_motion(p, rate_hz)) for p in paths]
    return motions


def _others(motions, k: int) -> list[np.ndarray]:
    """Other complete takes whose joint names match take ``k`` (reordered to it)."""
    from ..io.training_sets import match_joints

    name_k = motions[k][1].skeleton.joint_names
    out = []
    for i, (_, m) in enumerate(motions):
        if i == k or not m.observed.all():
            continue
        idx = match_joints(m.skeleton.joint_names, name_k)
        if idx is not None:
            out.append(m.positions[:, idx])
    return out


def _record(path, motion, protocol, level, method, pred, truth, dt, **extra) -> dict:
    bones = motion.skeleton.bone_array
    return {
        "file": path,
        "rate_hz": motion.rate_hz,
        "protocol": protocol,
        "level": float(level),
        "method": method,
        "n_frames": motion.n_frames,
        "n_joints": motion.n_joints,
        "aje_m": metrics.aje(pred, truth) if truth is not None else None,
        "abe_m": metrics.abe(pred, truth, bones) if truth is not None and len(bones) else None,
        "jitter": metrics.jitter(pred),
        "time_s": dt,
        **extra,
    }


def run_long_gaps(paths, *, rate_hz=None, levels=None, seed=0, methods=None) -> list[dict]:
    """The long-gap protocol (see the module doc); one record per file x config x method."""
    names = _available(methods)
    motions = _load(paths, rate_hz)
    records: list[dict] = []
    for k, (path, motion) in enumerate(motions):
        truth = motion.positions
        obs_all = motion.observed
        ctx_base = {"window": max(int(round(BLACKOUT_WINDOW_S * motion.rate_hz)), 20), "skeleton": motion.skeleton,
                    "rate_hz": motion.rate_hz}
        if not obs_all.all():
            # real gaps: no ground truth, judge plausibility of the fill
            pairs = pg.estimate_rigid_pairs(truth, obs_all, k=pg_pairs(motion))
            lo, hi = pg.pair_distance_ranges(truth, obs_all, pairs)
            own = np.where(obs_all[..., None], truth, np.nan)
            ctx = dict(ctx_base, training=pg.TrainingSet([own]), partners=pg._partner_ranking(own, obs_all),
                       training_ref=pg.TrainingSet([own] + _others(motions, k)))
            for name in names:
                pred, dt = _run_method(name, truth, obs_all, ctx)
                fil = ~obs_all & np.isfinite(pred).all(axis=2)
                raw = pg.pair_distance_plausibility(pred, obs_all, fil, pairs)
                if name == "pca" and len(pairs):             # what streamfix clean writes
                    pred = pg.project_pair_distances(pred, fil, pairs, lo, hi)
                records.append(_record(path, motion, "long-gaps", round(100.0 * (~obs_all).mean(), 2), name, pred, None, dt,
                                       gap_frames=None, gap_count=None, gap_mae_m=None,
                                       plausibility=pg.pair_distance_plausibility(pred, obs_all, fil, pairs),
                                       plausibility_raw=raw, rigid_pairs=int(len(pairs)), real_gaps=True))
            continue
        for count, length in gap_configs(levels):
            rng = _rng(seed, "long-gaps", f"{count}x{length}", path)
            miss, gaps = make_gaps(motion.n_frames, motion.n_joints, count, length, rng)
            obs = ~miss
            own = np.where(obs[..., None], truth, np.nan)
            # gapfill's partner markers are chosen on the corrupted take too (never the gap)
            ctx = dict(ctx_base, training=pg.TrainingSet([own]), partners=pg._partner_ranking(own, obs),
                       training_ref=pg.TrainingSet([own] + _others(motions, k)))
            gap_idx = [(np.arange(s, e), np.full(e - s, j)) for j, s, e in gaps]
            for name in names:
                pred, dt = _run_method(name, truth, obs, ctx)
                records.append(_record(path, motion, "long-gaps", round(100.0 * miss.mean(), 2), name, pred, truth, dt,
                                       gap_frames=int(length), gap_count=int(len(gaps)),
                                       gap_mae_m=eq17_mae(pred, truth, gap_idx)))
    return records


def pg_pairs(motion) -> int:
    """Rigid pairs checked for a take with real gaps (60, fewer for small sets)."""
    return int(min(60, motion.n_joints * (motion.n_joints - 1) // 4))


def run_blackout(paths, *, rate_hz=None, levels=None, seed=0, methods=None) -> list[dict]:
    """Whole-frame blackouts of ``level`` % of a window (see the module doc)."""
    # rigid-body / donor fills need an observed partner marker: none in a blackout
    names = [n for n in _available(methods) if n not in ("gapfill-rbt", "gapfill-pattern")]
    motions = _load(paths, rate_hz)
    levels = list(levels or BLACKOUT_LEVELS)
    records: list[dict] = []
    for k, (path, motion) in enumerate(motions):
        truth = motion.positions
        if not motion.observed.all():
            continue                                         # needs ground truth
        m = min(max(int(round(BLACKOUT_WINDOW_S * motion.rate_hz)), 20), motion.n_frames)
        T_len = motion.n_frames
        starts = np.linspace(0, T_len - m, BLACKOUT_WINDOWS).astype(int)
        others = _others(motions, k)
        for level in levels:
            L = max(int(round(level / 100.0 * m)), 1)
            per: dict[str, list] = {n: [] for n in names}
            for s in starts:
                a = s + (m - L) // 2
                miss = np.zeros(truth.shape[:2], dtype=bool)
                miss[a:a + L] = True
                obs = ~miss
                # training: the take outside the test window, plus other takes
                own = [t for t in (truth[:s], truth[s + m:]) if len(t) >= m] or [truth[:0]]
                ctx = {"training": pg.TrainingSet(own), "training_ref": pg.TrainingSet(own + others),
                       "window": m, "partners": None, "skeleton": motion.skeleton, "rate_hz": motion.rate_hz}
                for name in names:
                    pred, dt = _run_method(name, truth, obs, ctx)
                    per[name].append((eq17_mae(pred, truth, [(np.arange(a, a + L)[:, None],
                                                              np.arange(motion.n_joints)[None, :])]),
                                      metrics.aje(pred, truth), metrics.jitter(pred), dt))
            for name in names:
                v = np.asarray(per[name], dtype=np.float64)
                records.append({
                    "file": path, "rate_hz": motion.rate_hz, "protocol": "blackout", "level": float(level),
                    "method": name, "n_frames": motion.n_frames, "n_joints": motion.n_joints,
                    "aje_m": float(v[:, 1].mean()), "abe_m": None, "jitter": float(v[:, 2].mean()),
                    "time_s": float(v[:, 3].mean()), "gap_frames": L, "gap_count": len(starts),
                    "gap_mae_m": float(v[:, 0].mean()), "window_frames": m,
                })
    return records


PROTOCOLS = {"long-gaps": run_long_gaps, "blackout": run_blackout}
