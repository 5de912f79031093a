"""Benchmark of the learned prior (issues 4 and 9): latency on one core, held-out quality, solver init.

Prints four tables, writes ``benchmarks/results/prior.json`` and exits 1 when a target is missed:

1. Latency, one core, a 2 s Kinect v2 window (60 frames at 30 Hz) with a leg missing: the
   prior's share of the window's compute as the streaming bridge runs it
   (``fill_long_gaps``: layout -> canonical, D(z*), back; target p99 < 5 ms; the bridge calls it
   once per window solve, on one prior window), the same with D(E(Y)), the bridge's whole
   prior source per hop over a take (history, run lengths, excursion limit included), D(E(Y))
   as the solver's start and the leave-one-limb-out plausibility score, with the ALM solver
   timed in the same run for scale. Judged on the thread's CPU time (everything
   is single-threaded), which leaves out the time other jobs get, though not the slowdown of a
   core whose neighbour is busy (small numpy and onnxruntime calls suffer most; the ALM
   baseline beside it shows the machine's state).
2. Held-out quality (Lohit et al. Tables 1 and 3) in canonical joints on the held-out
   people/takes (UI-PRMD subject 6 from its Vicon markers, CMU 131_02, Xia neutral_01_000,
   Kinect v2 Ges04): RMSE over all joint-frames of D(z*), D(E(Y)) and the nearest-joint
   baseline, random 50 % / 25 % of the joints or a whole limb hidden for each window.
   Targets: D(z*) < 6 cm at OTP 50 % and < 8 cm with a limb hidden on the UI-PRMD person
   and the CMU/Xia takes; D(z*) below D(E(Y)) and nearest-joint in every cell.
3. The same windows in each sensor layout (Kinect v2, Azure Kinect, Kinect v1, COCO-17,
   BlazePose) mapped from the held-out UI-PRMD person: D(z*) RMSE on the joints the layout lacks.
4. The ALM solver (Yang et al., mode 'yang') alone vs initialised from D(z*) on the Kinect v2
   held-out takes (issue 4: initialised RMSE <= alone, iterations <= half).
5. ``streamfix eval --protocol occlusion`` on the held-out BVH/Kinect takes: the default
   ``streamfix`` method (the engine's window solver) within 1.1x of ``prior_latent``'s RMSE in
   every cell (issue 9), with ``clean_window`` alone beside it.

Usage: python benchmarks/bench_prior.py [--data ../shared/data] [--repeats 200] [--uiprmd-takes 60]
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core: BLAS and onnxruntime single-threaded
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from streamfix.canonical import CANONICAL_JOINTS, LAYOUTS  # noqa: E402
from streamfix.evaluation.occlusion import _solver, drop_masks, score_prior_on_takes  # noqa: E402
from streamfix.io.prior_takes import uiprmd_takes  # noqa: E402
from streamfix.prior.data import HELD_OUT, cut_windows, load_take, resample_masked  # noqa: E402
from streamfix.prior.init import fill_long_gaps, prior_initial_guess  # noqa: E402
from streamfix.prior.plausibility import limb_residuals  # noqa: E402
from streamfix.prior.runtime import Prior, sha256_file  # noqa: E402
from streamfix.skeletons import KINECT_V2  # noqa: E402

HERE = Path(__file__).resolve().parent


def _timed(fn, repeats: int) -> dict:
    """p50/p99 CPU time of this thread and p50 wall time, ms, of ``fn`` over ``repeats`` calls after 3 warm-ups.

    Everything runs on this one thread (onnxruntime intra-op threads = 1, BLAS threads = 1),
    so the thread's CPU time is the one-core cost; on a machine shared with other jobs the
    wall time also counts the time the scheduler gave to them.
    """
    for _ in range(3):
        fn()
    cpu = np.empty(repeats)
    wall = np.empty(repeats)
    for i in range(repeats):
        c0, t0 = time.thread_time(), time.perf_counter()
        fn()
        cpu[i], wall[i] = time.thread_time() - c0, time.perf_counter() - t0
    return {"cpu_p50_ms": 1e3 * float(np.median(cpu)), "cpu_p99_ms": 1e3 * float(np.percentile(cpu, 99)),
            "wall_p50_ms": 1e3 * float(np.median(wall))}


def _kinect_windows(data: Path, prior: Prior, seed: int):
    """(name, truth, truth mask, keep mask) for every 64-frame window of the Kinect v2 / BVH held-out takes (Kinect v2 layout)."""
    paths = {p.stem: p for p in list(data.glob("*_bvh/*.bvh")) + list(data.glob("kinect_v2/*.csv"))}
    out = []
    rng = np.random.default_rng(seed)
    for name in HELD_OUT:
        if name not in paths:
            continue
        take = load_take(paths[name])
        pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, prior.rate_hz)
        wins, masks, _ = cut_windows(pos, obs, prior.window, prior.window)
        keep = drop_masks(len(wins), KINECT_V2.n_joints, prior.window, "random", 50.0, rng)
        for w, m, k in zip(wins, masks, keep):
            out.append((name, np.nan_to_num(w), m, k))
    return out


def _bridge_hops(take, leg: list[int], prior: Prior) -> list:
    """What the streaming bridge asks of the prior over a take: for every hop (10 frames) of a 60-frame
    window whose right leg has been missing since 1 s before it, the history (the engine's clean output
    so far, here the tracked data) and the window. Each call fills from one prior window (``bridging``)."""
    from streamfix.streaming.bridging import BridgingWindowSolver

    solver = BridgingWindowSolver(sources=("prior",))
    x = np.where(take.observed[..., None], take.positions, np.nan)
    calls = []
    for end in range(90, len(x) + 1, 10):  # hops of 10 frames
        win = x[end - 60:end].copy()
        win[:, leg] = np.nan
        calls.append(lambda w=win, h=x[:end - 60]: solver.bridge(w, np.isfinite(w).all(axis=2), 30.0, h, "kinect_v2"))
    return calls


def _latency(data: Path, prior: Prior, repeats: int, failures: list) -> dict:
    take = load_take(data / "kinect_v2" / "Ges04_comehere.csv")
    x = np.nan_to_num(take.positions[:60])
    obs = take.observed[:60].copy()
    obs[:, [KINECT_V2.index(n) for n in ("HipRight", "KneeRight", "AnkleRight", "FootRight")]] = False
    bones = KINECT_V2.bone_array
    leg = [KINECT_V2.index(n) for n in ("HipRight", "KneeRight", "AnkleRight", "FootRight")]
    hops = _bridge_hops(take, leg, prior)
    hop_i = itertools.count()
    rows = {
        "fill_long_gaps D(z*) (the bridge's default)": (
            _timed(lambda: fill_long_gaps(x, obs, 30.0, min_gap_frames=15, prior=prior), repeats), 5.0),
        "fill_long_gaps D(E(Y)) (method='encode')": (
            _timed(lambda: fill_long_gaps(x, obs, 30.0, min_gap_frames=15, prior=prior, method="encode"), repeats),
            None),
        "bridge per hop, prior source (one prior window)": (
            _timed(lambda: hops[next(hop_i) % len(hops)](), repeats), None),
        "prior_initial_guess D(E(Y)) (solver start)": (
            _timed(lambda: prior_initial_guess(x, obs, 30.0, prior=prior, method="encode"), repeats), None),
        "limb_residuals (plausibility, 5 limbs)": (_timed(lambda: limb_residuals(x, obs, 30.0, prior=prior),
                                                          max(repeats // 5, 10)), None),
        "limb_residuals method='encode'": (_timed(lambda: limb_residuals(x, obs, 30.0, prior=prior, method="encode"),
                                                  repeats), None),
        "baseline: ALM solver 'yang' alone": (_timed(lambda: _solver(x, obs, bones, None), 5), None),
    }
    print("1. latency, one core, a 2 s Kinect v2 window (60 frames, right leg missing): CPU ms (target) and wall ms")
    print(f"  {'what':<52s} {'cpu p50':>8s} {'cpu p99':>8s} {'wall p50':>9s} {'target':>10s}")
    out = {}
    for name, (t, target) in rows.items():
        print(f"  {name:<52s} {t['cpu_p50_ms']:8.2f} {t['cpu_p99_ms']:8.2f} {t['wall_p50_ms']:9.2f} "
              f"{('p99 < %g' % target) if target else '':>10s}")
        if target is not None and not t["cpu_p99_ms"] < target:
            failures.append(f"{name}: p99 {t['cpu_p99_ms']:.2f} ms CPU >= {target} ms")
        out[name] = t | ({"target_p99_ms": target} if target else {})
    solver = rows["baseline: ALM solver 'yang' alone"][0]["cpu_p50_ms"]
    share = list(rows.values())[0][0]["cpu_p50_ms"]
    print(f"  ratio prior share / ALM solver alone (CPU p50): {share / solver:.3f}")
    return out


def _held_out_takes(data: Path, n_uiprmd: int) -> list:
    from streamfix.io.prior_takes import canonical_takes
    from streamfix.prior.data import split_takes

    _, held = split_takes(canonical_takes(data, markers=False, kinect_v1=False))
    ui = [t for t in held if t.group == "uiprmd_s06"]
    step = max(1, int(np.ceil(len(ui) / n_uiprmd))) if n_uiprmd else 1
    return [t for t in held if t.group != "uiprmd_s06"] + ui[::step]


def _quality(takes: list, prior: Prior, seed: int, failures: list) -> list[dict]:
    recs = score_prior_on_takes(prior.directory / prior.card_name, takes, seed=seed)
    print("\n2. held-out people/takes, canonical joints: RMSE over all joint-frames, cm (dropped joints only in brackets)")
    print(f"  {'take':<16s} {'pattern':<10s} {'OTP':>5s} {'win':>4s} {'nearest':>15s} {'D(E(Y))':>15s} {'D(z*)':>15s}")
    cells: dict = {}
    for r in recs:
        cells.setdefault((r["take"], r["pattern"], r["test_otp"]), {})[r["method"]] = r
    for (take, pattern, otp), c in cells.items():
        f = lambda m: f"{100 * c[m]['rmse_m']:6.2f} ({100 * c[m]['rmse_dropped_m']:5.1f})"  # noqa: E731
        print(f"  {take:<16s} {pattern:<10s} {otp:5.0f} {c['prior_latent']['windows']:4d} "
              f"{f('nearest_joint'):>15s} {f('prior_encode'):>15s} {f('prior_latent'):>15s}")
        lat = c["prior_latent"]["rmse_m"]
        if not (lat < c["prior_encode"]["rmse_m"] and lat < c["nearest_joint"]["rmse_m"]):
            failures.append(f"{take} {pattern} OTP {otp:.0f}: D(z*) {100 * lat:.2f} cm is not below D(E(Y)) and nearest-joint")
        if take == "Ges04_comehere":
            continue  # Kinect v2 truth is the sensor's own tracking: compared, not held to the bars
        bar = 0.06 if pattern == "random" and otp == 50 else 0.08 if pattern != "random" else None
        if bar is not None and not lat < bar:
            failures.append(f"{take} {pattern} OTP {otp:.0f}: D(z*) {100 * lat:.2f} cm >= {100 * bar:.0f} cm")
    return recs


def _layouts(data: Path, prior: Prior, seed: int, n_takes: int) -> dict:
    takes = uiprmd_takes(data, "vicon", subjects=(6,))[:: max(1, 200 // max(n_takes, 1))]
    rng = np.random.default_rng(seed)
    print("\n3. the held-out UI-PRMD person seen through each layout: D(z*) RMSE on the canonical joints the layout "
          "lacks, plus a random 25 % of the rest hidden, cm")
    out = {}
    for name, lay in LAYOUTS.items():
        if name == "canonical":
            continue
        sq, n = 0.0, 0
        for t in takes:  # takes, not frames
            pos, obs = resample_masked(t.positions, t.observed, t.rate_hz, prior.rate_hz)
            x = np.nan_to_num(pos)
            # canonical truth -> a layout-like input: keep what the layout covers, drop 25 % more
            keep = obs & lay.covered[None, :]
            keep[:, rng.choice(len(CANONICAL_JOINTS), size=5, replace=False)] = False
            est = prior_initial_guess(x, keep, prior.rate_hz, prior=prior, method="latent")
            miss = obs & ~keep
            sq += float(((est - x) ** 2).sum(-1)[miss].sum())
            n += int(miss.sum())
        out[name] = {"rmse_missing_m": float(np.sqrt(sq / max(n, 1))), "joint_frames": n}
        print(f"  {name:<18s} observes {int(lay.covered.sum()):2d}/20 canonical joints   "
              f"RMSE on missing {100 * out[name]['rmse_missing_m']:6.2f} cm")
    return out


def _solver_init(windows: list, prior: Prior, failures: list) -> dict:
    bones = KINECT_V2.bone_array
    print("\n4. ALM solver ('yang', tol 1e-6) alone vs initialised from D(z*), Kinect v2 layout, held-out windows "
          "at test OTP 50 %")
    tot = np.zeros(6)
    for name, gt, m, k in windows:
        obs = m & k
        t0 = time.perf_counter()
        a, it_a = _solver(gt, obs, bones, None)
        ta = time.perf_counter() - t0
        t0 = time.perf_counter()
        init = prior_initial_guess(gt, obs, prior.rate_hz, prior=prior, method="latent")
        b, it_b = _solver(gt, obs, bones, init)
        tb = time.perf_counter() - t0  # includes the prior's D(z*)
        e = lambda x: float(((x - gt) ** 2).sum(-1)[m].sum())  # noqa: E731
        tot += np.array([it_a, it_b, 1e3 * ta, 1e3 * tb, e(a), e(b)])
    n = len(windows)
    n_gt = sum(int(m.sum()) for _, _, m, _ in windows)
    rmse_a, rmse_b = 100 * np.sqrt(tot[4] / n_gt), 100 * np.sqrt(tot[5] / n_gt)
    print(f"  {n} windows: iterations {tot[0] / n:.1f} alone, {tot[1] / n:.1f} initialised (ratio {tot[1] / tot[0]:.2f}, "
          f"target <= 0.5); RMSE {rmse_a:.2f} cm alone, {rmse_b:.2f} cm initialised; wall ms {tot[2] / n:.1f} / {tot[3] / n:.1f}")
    if not rmse_b <= rmse_a:
        failures.append(f"solver from the prior is less accurate ({rmse_b:.2f} cm) than alone ({rmse_a:.2f} cm)")
    if not tot[1] <= 0.5 * tot[0]:
        failures.append(f"solver from the prior needs {tot[1] / tot[0]:.2f}x the iterations (target <= 0.5)")
    return {"windows": n, "iterations_alone": tot[0] / n, "iterations_init": tot[1] / n,
            "rmse_alone_m": rmse_a / 100, "rmse_init_m": rmse_b / 100}


def _occlusion_default(data: Path, prior: Prior, seed: int, failures: list) -> list[dict]:
    """``streamfix eval --protocol occlusion`` on the held-out BVH/Kinect takes: the default ``streamfix``
    method (the engine's window solver, what ``clean``/``serve`` run) against ``prior_latent``; bar 1.1x."""
    from streamfix.evaluation.occlusion import run

    paths = [p for name in HELD_OUT for p in list(data.glob(f"*_bvh/{name}.bvh")) + list(data.glob(f"kinect_v2/{name}.csv"))]
    recs = run(paths, rate_hz=30.0, seed=seed, methods=["prior_latent", "clean_window", "streamfix"],
               prior_path=str(prior.directory / prior.card_name))
    print("\n5. occlusion protocol (whole joints dropped per window), held-out takes: RMSE cm; bar streamfix <= 1.1x D(z*)")
    print(f"  {'take':<16s} {'pattern':<10s} {'level':>5s} {'D(z*)':>7s} {'clean_window':>12s} {'streamfix':>9s} {'ratio':>6s}")
    cells: dict = {}
    for r in recs:
        cells.setdefault((Path(r["file"]).stem, r["pattern"], r["level"]), {})[r["method"]] = r["rmse_m"]
    out = []
    for (take, pattern, level), c in cells.items():
        ratio = c["streamfix"] / c["prior_latent"]
        print(f"  {take:<16s} {pattern:<10s} {level:5.0f} {100 * c['prior_latent']:7.2f} {100 * c['clean_window']:12.2f} "
              f"{100 * c['streamfix']:9.2f} {ratio:6.2f}")
        if not ratio <= 1.1:
            failures.append(f"occlusion {take} {pattern} {level:.0f}: streamfix {ratio:.2f}x D(z*) (bar 1.1x)")
        out.append({"take": take, "pattern": pattern, "level": level, "ratio": round(ratio, 3),
                    **{f"rmse_m_{m}": round(v, 5) for m, v in c.items()}})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str((HERE / ".." / ".." / "shared" / "data").resolve()))
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--uiprmd-takes", type=int, default=0,
                    help="UI-PRMD subject-6 repetitions scored (default 0: all of them, as the model card)")
    ap.add_argument("--prior", default=None, help="model card (default: the shipped one)")
    ap.add_argument("--out", default=str(HERE / "results" / "prior.json"))
    args = ap.parse_args()
    data = Path(args.data)
    prior = Prior.load(args.prior, threads=1)
    failures: list[str] = []
    results = {"prior": prior.card.get("name"), "card_sha256": sha256_file(prior.directory / prior.card_name)}
    results["latency"] = _latency(data, prior, args.repeats, failures)
    results["held_out"] = _quality(_held_out_takes(data, args.uiprmd_takes), prior, args.seed, failures)
    results["layouts"] = _layouts(data, prior, args.seed, 20)
    results["solver_init"] = _solver_init(_kinect_windows(data, prior, args.seed), prior, failures)
    results["occlusion_default"] = _occlusion_default(data, prior, args.seed, failures)
    results["missed"] = failures
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(f"\nwrote {out}")
    if failures:
        print("\nMISSED:\n  " + "\n  ".join(failures))
        return 1
    print("\nall targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
