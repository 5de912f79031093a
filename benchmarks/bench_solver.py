"""Solver speed: Yang et al.'s Table VI case (272 frames) solved whole on one core.

CMU 131_01, first 272 frames at 120 Hz, 31 joints, 10 % of the entries of D corrupted
with uniform [-0.25, 0.25] m noise (the paper's protocol, fixed seed). The published
MATLAB solver took 24.7 s for a 272-frame clip (Table VI); the target here is
< 0.25 s on one core at the issue's accuracy (AJE <= 0.006 m at 10 %, Table II).

Time is the best of N runs, as CPU time of this single-threaded process
(``time.process_time``; BLAS pinned to one thread): on a shared, busy machine wall time
measures the other tenants, CPU time measures the solver. Wall time is printed too. A
Savitzky-Golay pass over the same clip (``streamfix.core.filters.savgol``) is timed in
the same run as the throughput baseline.

Exit status 1 when the time or accuracy target is missed.
Run: ``python benchmarks/bench_solver.py [--repeats N] [--data DIR]``
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from streamfix.core.alm import SolverParams, solve  # noqa: E402
from streamfix.core.corruption import add_noise  # noqa: E402
from streamfix.core.filters import savgol  # noqa: E402
from streamfix.core.metrics import aje  # noqa: E402
from streamfix.io.bvh import read_bvh  # noqa: E402

TARGET_S = 0.25
TARGET_AJE_M = 0.006  # Yang et al. Table II total at 10 %
N_FRAMES = 272
FRACTION = 0.10
SEED = 0


def _time(fn, repeats: int) -> tuple[float, float, object]:
    """Best CPU and best wall seconds over ``repeats`` calls, and the last result."""
    best_cpu = best_wall = float("inf")
    out = None
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        best_cpu = min(best_cpu, time.process_time() - c0)
        best_wall = min(best_wall, time.perf_counter() - w0)
    return best_cpu, best_wall, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
    args = ap.parse_args(argv)

    motion = read_bvh(args.data / "cmu_bvh" / "131_01.bvh")
    truth = motion.positions[:N_FRAMES]
    bones = motion.skeleton.bone_array
    D, _ = add_noise(truth, FRACTION, np.random.default_rng(SEED))
    rate = motion.rate_hz

    rows = []
    sg_cpu, sg_wall, sg_out = _time(lambda: savgol(D, rate), max(args.repeats, 20))
    rows.append(("savgol (baseline)", "-", sg_cpu, sg_wall, aje(sg_out, truth)))
    results = {}
    for mode in ("wang", "li", "yang"):
        cpu, wall, res = _time(lambda m=mode: solve(D, None, bones, params=SolverParams(mode=m)), args.repeats)
        results[mode] = (cpu, res)
        rows.append((f"solve mode={mode}", str(res.iterations), cpu, wall, aje(res.positions, truth)))

    print(f"CMU 131_01 frames 0-{N_FRAMES - 1} @ {rate:g} Hz, {truth.shape[1]} joints, "
          f"{FRACTION:.0%} entries corrupted (U[-0.25, 0.25] m, seed {SEED}); best of {args.repeats}")
    print(f"{'method':22s} {'iters':>5s} {'cpu s':>8s} {'wall s':>8s} {'frames/s':>10s} {'x savgol':>9s} {'AJE m':>8s}")
    for name, iters, cpu, wall, err in rows:
        fps = N_FRAMES / cpu if cpu > 0 else float("inf")
        print(f"{name:22s} {iters:>5s} {cpu:8.4f} {wall:8.4f} {fps:10.0f} {cpu / sg_cpu:9.1f} {err:8.4f}")

    cpu, res = results["yang"]
    err = aje(res.positions, truth)
    ok_time = cpu < TARGET_S
    ok_acc = err <= TARGET_AJE_M and res.converged
    print(f"target: yang < {TARGET_S} s on one core: {cpu:.3f} s {'OK' if ok_time else 'MISSED'}; "
          f"AJE <= {TARGET_AJE_M} m and converged: {err:.4f} m {'OK' if ok_acc else 'MISSED'} "
          f"(paper's MATLAB: 24.7 s, {24.7 / cpu:.0f}x slower)")
    return 0 if (ok_time and ok_acc) else 1


if __name__ == "__main__":
    sys.exit(main())
