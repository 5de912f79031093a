"""Occlusion protocol of Lohit et al. (Sec. 7.2, Tables 1-3) on our held-out takes.

Each file is converted to the Kinect v2 layout (BVH retargeted; Kinect CSV: tracked
joints are the ground truth, the rest is not scored), resampled to ``rate_hz`` and cut
into windows of the prior's duration (64 frames at 30 Hz = 2.13 s; the last window is
aligned to the end). In each window a set of joints is dropped **for the whole
window** (the paper's setting):

* ``pattern="random"``: a random subset of ``level`` % of the 25 joints (test OTP =
  100 - level: the paper's 75 % and 50 % are levels 25 and 50), a new subset per
  window (seeded);
* ``pattern="right_arm" | "left_arm" | "right_leg" | "left_leg"``: the paper's
  structured masks (Table 3): 6 arm joints (24 %) or 4 leg joints (16 %).

Every method then reconstructs each window on its own, and we score against the
ground truth: ``rmse_m`` = sqrt(mean over ground-truth joint-frames of ||X - X^||^2)
(Sec. 6.1), ``rmse_dropped_m`` the same over dropped joints only, ``aje_m``/``abe_m``
(Yang et al. Sec. IV), ``jitter`` (m/frame^2, mean |second difference| within windows),
``iterations`` (solver methods) and ``time_ms`` per window.

Methods: ``nearest_joint`` (baseline: linear interpolation in time where the joint is
seen in the window, else the nearest observed joint along the skeleton's bones; the
paper's "closest observed joint" baseline), ``prior_encode`` (D(E(Y))),
``prior_latent`` (D(z*), Eq. 1), ``yang`` (the ALM solver alone), ``yang_prior_init``
(the solver initialised from D(z*), with its initial penalty raised to trust the
initialisation, see ``streamfix.prior.init.solver_params_for_prior_init``), ``streamfix``
(the default: the engine's window solver ``streamfix.streaming.engine.default_window_solver``,
what ``streamfix clean`` and serve's ``clean`` topic run on a window; each window alone, so
with no history the long-missing joints are bridged by the prior), ``clean_window`` (the
window pipeline ``streamfix.core.pipeline.clean_window`` alone, without the bridge) and
``streamfix_prior_init`` (``clean_window`` with ``init=`` D(z*)) when the pipeline is
available. The prior methods return observed joints unchanged (fit tolerance 0,
``streamfix.prior.latent``).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from streamfix.core import metrics
from streamfix.core.interpolate import interpolate_linear
from streamfix.skeletons import KINECT_V2

__all__ = [
    "PROTOCOLS",
    "run",
    "drop_masks",
    "nearest_joint_fill",
    "score_prior_on_takes",
    "METHODS",
]

METHODS = ("nearest_joint", "prior_encode", "prior_latent", "yang", "yang_prior_init", "clean_window", "streamfix_prior_init",
           "streamfix")
DEFAULT_LEVELS = (25, 50)
LIMB_PATTERNS = ("right_arm", "left_arm", "right_leg", "left_leg")


def _graph_distances(n_joints: int, bones: np.ndarray) -> np.ndarray:
    """All-pairs hop distances along the bones (J, J)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    a = coo_matrix((np.ones(len(bones)), (bones[:, 0], bones[:, 1])), shape=(n_joints, n_joints))
    return shortest_path(a, directed=False, unweighted=True)


def nearest_joint_fill(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Baseline: temporal linear interpolation, then each never-seen joint copies the nearest seen joint."""
    x, _ = interpolate_linear(np.where(observed[..., None], positions, np.nan), observed)
    seen = np.isfinite(x).all(axis=-1).all(axis=0)  # (J,) joint has values in every frame
    if not seen.any():
        return np.zeros_like(x)
    dist = _graph_distances(x.shape[1], bones)
    dist = np.where(seen[None, :], dist, np.inf)
    dist[np.arange(len(seen)), np.arange(len(seen))] = np.where(seen, 0.0, np.inf)
    src = np.argmin(dist, axis=1)  # nearest seen joint (itself when seen)
    return x[:, src]


def drop_masks(
    n_windows: int, n_joints: int, window: int, pattern: str, level: float, rng: np.random.Generator,
    limbs: dict | None = None,
) -> np.ndarray:
    """(W, window, J) bool keep-masks: joints dropped for whole windows by ``pattern``/``level`` %.

    ``limbs``: limb name -> joint indices of the layout (default: Kinect v2's)."""
    from streamfix.prior.normalize import KINECT_V2_LIMBS

    limbs = KINECT_V2_LIMBS if limbs is None else limbs
    keep = np.ones((n_windows, window, n_joints), dtype=bool)
    if pattern == "random":
        k = int(round(level / 100.0 * n_joints))
        for w in range(n_windows):  # windows
            keep[w, :, rng.choice(n_joints, size=k, replace=False)] = False
    else:
        keep[:, :, list(limbs[pattern])] = False
    return keep


def _solver(d: np.ndarray, obs: np.ndarray, bones: np.ndarray, init: np.ndarray | None):
    from streamfix.core.alm import SolverParams, solve
    from streamfix.prior.init import solver_params_for_prior_init

    params = SolverParams() if init is None else solver_params_for_prior_init(d, obs)
    res = solve(np.where(obs[..., None], d, np.nan), obs, bones, params=params, init=init)
    return res.positions, res.iterations


def _make_methods(prior, rate_hz: float, bones: np.ndarray, skeleton=None) -> dict[str, Callable]:
    """The protocol's methods by name; ``skeleton`` (a ``streamfix.skeletons.Skeleton``) is told to the default solver."""
    from streamfix.prior.init import prior_initial_guess

    def prior_encode(d, obs):
        return prior_initial_guess(d, obs, rate_hz, prior=prior, method="encode"), 0

    def prior_latent(d, obs):
        return prior_initial_guess(d, obs, rate_hz, prior=prior, method="latent"), 0

    def yang(d, obs):
        return _solver(d, obs, bones, None)

    def yang_prior_init(d, obs):
        init = prior_initial_guess(d, obs, rate_hz, prior=prior, method="latent")
        return _solver(d, obs, bones, init)

    def nearest(d, obs):
        return nearest_joint_fill(d, obs, bones), 0

    methods = {
        "nearest_joint": nearest,
        "prior_encode": prior_encode,
        "prior_latent": prior_latent,
        "yang": yang,
        "yang_prior_init": yang_prior_init,
    }
    try:
        from streamfix.core.pipeline import PipelineConfig, clean_window

        def streamfix_method(d, obs):
            conf = np.where(obs, 1.0, 0.0)
            res = clean_window(np.where(obs[..., None], d, np.nan), conf, bones, None, rate_hz, PipelineConfig())
            return res.positions, int(getattr(res, "iterations", 0) or 0)

        def streamfix_prior_init(d, obs):
            conf = np.where(obs, 1.0, 0.0)
            init = prior_initial_guess(d, obs, rate_hz, prior=prior, method="latent")
            res = clean_window(np.where(obs[..., None], d, np.nan), conf, bones, None, rate_hz, PipelineConfig(),
                               init=init)
            return res.positions, int(getattr(res, "iterations", 0) or 0)

        methods["clean_window"] = streamfix_method
        methods["streamfix_prior_init"] = streamfix_prior_init
    except Exception:  # pipeline not built (or its contract differs): method skipped
        pass
    try:
        from streamfix.streaming.engine import default_window_solver

        solver = default_window_solver()

        def streamfix_default(d, obs):
            # what `streamfix clean` / serve's clean topic run on a window (no history: each window alone)
            conf = np.where(obs, 1.0, 0.0)
            kwargs = {"skeleton": skeleton} if skeleton is not None and getattr(solver, "wants_skeleton", False) else {}
            res = solver(np.where(obs[..., None], d, np.nan), conf, bones, None, rate_hz, **kwargs)
            return np.asarray(res.positions), int(getattr(res, "iterations", 0) or 0)

        methods["streamfix"] = streamfix_default
    except Exception:  # pipeline not built (or its contract differs): method skipped
        pass
    return methods


def _evaluate_take(
    name: str,
    positions: np.ndarray,
    truth_obs: np.ndarray,
    rate_hz: float,
    patterns: list[tuple[str, float]],
    methods: dict[str, Callable],
    seed: int,
    window_s: float,
) -> list[dict]:
    from streamfix.prior.data import cut_windows

    w_len = max(int(round(window_s * rate_hz)), 8)
    wins, wmask, _ = cut_windows(positions, truth_obs, w_len, w_len)
    return _evaluate_windows(name, wins, wmask, rate_hz, patterns, methods, seed, KINECT_V2.bone_array)


def _evaluate_windows(
    name: str,
    wins: np.ndarray,
    wmask: np.ndarray,
    rate_hz: float,
    patterns: list[tuple[str, float]],
    methods: dict[str, Callable],
    seed: int,
    bones: np.ndarray,
    limbs: dict | None = None,
) -> list[dict]:
    """Score ``methods`` on windows (W, T, J, 3) with ground-truth masks (W, T, J) under each drop pattern."""
    w_len = wins.shape[1]
    records = []
    for p_i, (pattern, level) in enumerate(patterns):
        rng = np.random.default_rng([seed, p_i])
        keep = drop_masks(len(wins), wins.shape[2], w_len, pattern, level, rng, limbs)
        for method, fn in methods.items():
            sq, sq_drop, n_all, n_drop, ajes, abes, jits, iters, times = 0.0, 0.0, 0, 0, [], [], [], [], []
            errors: list[str] = []
            for w in range(len(wins)):  # windows
                gt, gt_obs = wins[w], wmask[w]
                obs = gt_obs & keep[w]
                if not obs.any():
                    continue
                t0 = time.perf_counter()
                try:
                    out, it = fn(np.nan_to_num(gt), obs)
                except Exception as exc:  # one method failing on a window must not lose the others' results
                    errors.append(f"{type(exc).__name__}: {exc}")
                    continue
                times.append(1e3 * (time.perf_counter() - t0))
                iters.append(it)
                err2 = ((out - np.nan_to_num(gt)) ** 2).sum(-1)
                sq += float(err2[gt_obs].sum())
                n_all += int(gt_obs.sum())
                dropped = gt_obs & ~keep[w]
                sq_drop += float(err2[dropped].sum())
                n_drop += int(dropped.sum())
                truth = np.where(gt_obs[..., None], gt, np.nan)
                ajes.append(metrics.aje(out, truth))
                abes.append(metrics.abe(out, truth, bones))
                jits.append(metrics.jitter(out))
            if errors and not n_all:
                records.append({"file": name, "rate_hz": float(rate_hz), "protocol": "occlusion", "pattern": pattern,
                                "level": float(level), "test_otp": 100.0 - float(level), "method": method,
                                "aje_m": float("nan"), "abe_m": float("nan"), "jitter": float("nan"),
                                "rmse_m": float("nan"), "rmse_dropped_m": float("nan"),
                                "failed_windows": len(errors), "error": errors[0]})
                continue
            if not n_all:
                continue
            records.append(
                {
                    "file": name,
                    "rate_hz": float(rate_hz),
                    "protocol": "occlusion",
                    "pattern": pattern,
                    "level": float(level),
                    "test_otp": 100.0 - float(level),
                    "method": method,
                    "aje_m": float(np.nanmean(ajes)),
                    "abe_m": float(np.nanmean(abes)),
                    "jitter": float(np.nanmean(jits)),
                    "rmse_m": float(np.sqrt(sq / n_all)),
                    "rmse_dropped_m": float(np.sqrt(sq_drop / n_drop)) if n_drop else float("nan"),
                    "iterations": float(np.mean(iters)),
                    "time_ms": float(np.mean(times)),
                    "windows": len(times),
                    **({"failed_windows": len(errors), "error": errors[0]} if errors else {}),
                }
            )
    return records


def _patterns(levels, n_joints: int | None = None, limbs: dict | None = None) -> list[tuple[str, float]]:
    """Random patterns at ``levels`` % and the four limb patterns (level = the limb's share of the joints)."""
    from streamfix.prior.normalize import KINECT_V2_LIMBS

    n_j = KINECT_V2.n_joints if n_joints is None else n_joints
    limbs = KINECT_V2_LIMBS if limbs is None else limbs
    pats = [("random", float(lv)) for lv in levels]
    pats += [(name, 100.0 * len(limbs[name]) / n_j) for name in LIMB_PATTERNS]
    return pats


def run(
    paths,
    *,
    rate_hz: float | None = 30.0,
    levels=DEFAULT_LEVELS,
    seed: int = 0,
    methods=None,
    prior_path: str | None = None,
) -> list[dict]:
    """The occlusion protocol on ``paths`` (BVH / Kinect v2 CSV). ``levels``: percent of joints
    dropped for the random pattern (limb patterns are always added). ``rate_hz`` None = native."""
    from streamfix.prior.data import load_take, resample_masked
    from streamfix.prior.runtime import Prior

    prior = Prior.load(prior_path)
    levels = tuple(levels) if levels else DEFAULT_LEVELS
    records = []
    for path in paths:
        take = load_take(path)
        rate = float(rate_hz) if rate_hz else take.rate_hz
        pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, rate)
        available = _make_methods(prior, rate, KINECT_V2.bone_array, KINECT_V2)
        chosen = {m: f for m, f in available.items() if methods is None or m in methods}
        records += _evaluate_take(
            str(path), pos, obs, rate, _patterns(levels), chosen, seed, prior.window / prior.rate_hz
        )
    return records


def score_prior_on_takes(card_path: str | Path, takes: list, seed: int = 0, max_takes_per_group: int | None = None) -> list[dict]:
    """Held-out scores for a model card on canonical takes (``streamfix.io.prior_takes``), as compact records.

    Prior methods and the nearest-joint baseline at the prior's rate, in canonical joints;
    takes of one group (a UI-PRMD person) are pooled into one row; Kinect v1 takes are
    skipped (no ground truth). ``max_takes_per_group`` keeps every n-th take of a large group.
    """
    from streamfix.canonical import CANONICAL_BONES, CANONICAL_LIMBS
    from streamfix.prior.data import cut_windows, resample_masked
    from streamfix.prior.runtime import Prior

    prior = Prior.load(card_path)
    methods = {k: v for k, v in _make_methods(prior, prior.rate_hz, CANONICAL_BONES).items()
               if k in ("nearest_joint", "prior_encode", "prior_latent")}
    groups: dict[str, list] = {}
    for take in takes:
        if take.source != "uiprmd_kinect_v1":
            groups.setdefault(take.group, []).append(take)
    out = []
    for group, members in groups.items():
        if max_takes_per_group and len(members) > max_takes_per_group:
            members = members[:: int(np.ceil(len(members) / max_takes_per_group))]
        wins, masks = [], []
        for take in members:  # takes, not frames
            pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, prior.rate_hz)
            w, m, _ = cut_windows(pos, obs, prior.window, prior.window)
            wins.append(w)
            masks.append(m)
        recs = _evaluate_windows(group, np.concatenate(wins), np.concatenate(masks), prior.rate_hz,
                                 _patterns(DEFAULT_LEVELS, prior.n_joints, CANONICAL_LIMBS), methods, seed,
                                 CANONICAL_BONES, CANONICAL_LIMBS)
        for r in recs:
            if "error" in r:  # a method failed on every window: a card must not hide it
                raise RuntimeError(f"held-out scoring of {r['method']} on {group} ({r['pattern']}) failed on "
                                   f"{r['failed_windows']} windows: {r['error']}")
            out.append({"take": group, "takes": len(members), "pattern": r["pattern"], "test_otp": round(r["test_otp"], 1),
                        "method": r["method"], "rmse_m": round(r["rmse_m"], 5),
                        "rmse_dropped_m": round(r["rmse_dropped_m"], 5), "windows": r["windows"],
                        "time_ms": round(r["time_ms"], 2)})
    return out


PROTOCOLS = {"occlusion": run}
