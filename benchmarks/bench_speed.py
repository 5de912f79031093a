"""Offline cleaning speed: frames per CPU second of ``streamfix clean`` beside the filters users compare it with.

Issue 13's targets, on one core: ``streamfix clean`` at least 10,000 frames/s of CPU time
and at most 7x the cost of median + Savitzky-Golay measured in the same run.

Inputs (real recordings from ``shared/data``):

* **Kinect v2, 30 Hz**: the five Kinect v2 CSVs played one after another until the take
  has ``--kinect-frames`` frames (10,000 by default); each copy's timestamps continue
  where the last ended, so the sensor's own dropped frames stay in.
* **BVH, 120 Hz**: CMU 131_01 and 131_02 (optical mocap, 31 joints) one after another
  (``--bvh-frames``, all 2,241 frames by default).
* **C3D markers with real gaps**: ``c3d/03_rolling.c3d`` (68 optical markers, a roll on the
  floor that hides about a quarter of the samples; ``--c3d-frames``, all by default), what a
  lab cleans: here the gap filling (:mod:`streamfix.gapfill`) does most of the work. No
  issue sets a target for it (``target`` "-"): the row shows where a marker take's time goes.

Timed: :func:`streamfix.cleaning.clean_recording` (what ``streamfix clean`` runs between
reading and writing the file), :func:`streamfix.core.filters.median_savgol` and
:func:`streamfix.core.filters.one_euro` on the same positions, as CPU time of this
process (``time.process_time``, BLAS pinned to one thread; best of ``--repeats`` runs for
each, the clean included: a first run also pays one-off costs such as lazy imports). File
reading and writing are not timed. The compiled kernels (:mod:`streamfix.core.kernels`,
numba) are compiled or loaded from their cache before timing. The process keeps the memory it
frees, as the ``streamfix`` command does (:func:`streamfix.allocator.keep_freed_memory`; the JSON
says whether it applied), so the clean's CPU time is what ``streamfix clean`` spends.
``--reference`` also times the clean with the kernels switched off (their numpy references,
the same output) in the same run, for the kernels' speed-up.

Writes ``benchmarks/results/speed.json`` (``--out``), prints a table, exits 1 when a target is missed;
beside it, the minor page faults of one more clean (untimed): pages the allocator gave back to the
system and mapped again, zeroed, which the clean's CPU time includes.
Run: ``python benchmarks/bench_speed.py [--quick] [--reference] [--profile 30] [--data DIR]``
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from streamfix.allocator import keep_freed_memory  # noqa: E402
from streamfix.cleaning import clean_recording  # noqa: E402
from streamfix.core import kernels  # noqa: E402
from streamfix.core.filters import median_savgol, one_euro  # noqa: E402
from streamfix.io import read_motion  # noqa: E402
from streamfix.motion import Motion  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = (HERE / ".." / ".." / "shared" / "data").resolve()
TARGET_FPS = 10_000.0
TARGET_RATIO = 7.0  # clean's CPU time over median + Savitzky-Golay's


def looped(motions: list[Motion], n_frames: int | None) -> Motion:
    """The motions one after another (repeated) up to ``n_frames``; timestamps continue across joins."""
    pos, conf, times, t_end = [], [], [], 0.0
    total, k = 0, 0
    limit = n_frames if n_frames is not None else sum(m.n_frames for m in motions)
    while total < limit:
        m = motions[k % len(motions)]
        take = min(m.n_frames, limit - total)
        t = np.asarray(m.timestamps[:take]) - m.timestamps[0] + t_end
        pos.append(m.positions[:take])
        conf.append(m.confidence[:take])
        times.append(t)
        t_end = t[-1] + 1.0 / m.rate_hz
        total += take
        k += 1
    first = motions[0]
    return Motion(np.concatenate(pos), np.concatenate(conf), np.concatenate(times), first.rate_hz, first.skeleton)


def cpu_seconds(fn, repeats: int) -> float:
    """Best CPU time of ``repeats`` calls of ``fn()``."""
    best = float("inf")
    for _ in range(repeats):
        c0 = time.process_time()
        fn()
        best = min(best, time.process_time() - c0)
    return best


def minor_page_faults(fn) -> int | None:
    """Minor page faults of this process during one call of ``fn()`` (None where the platform has no
    ``resource``). Why: a fault maps a fresh page (zeroed) for memory the allocator handed back to the
    system and asks for again; a 120 Hz file's window arrays are megabytes each, and their faults are
    part of the clean's CPU time with glibc's defaults (:func:`keep_freed_memory` leaves almost none)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not Unix
        return None
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    fn()
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)


def reference_cpu_seconds(motion: Motion) -> float:
    """CPU time of the clean with the compiled kernels off (their numpy references)."""
    saved = kernels.COMPILED
    kernels.COMPILED = False
    try:
        return cpu_seconds(lambda: clean_recording(motion), 1)
    finally:
        kernels.COMPILED = saved


def measure(name: str, motion: Motion, repeats: int, reference: bool = False, targets: bool = True) -> dict:
    x, obs, rate = motion.positions, motion.observed, motion.rate_hz
    clean_recording(motion.slice(0, min(motion.n_frames, 100)))  # compile / load the kernels, untimed
    clean_s = cpu_seconds(lambda: clean_recording(motion), repeats)
    msg_s = cpu_seconds(lambda: median_savgol(x, rate, obs), repeats)
    euro_s = cpu_seconds(lambda: one_euro(x, rate, obs), repeats)
    n = motion.n_frames
    row = {
        "input": name, "frames": n, "joints": motion.n_joints, "rate_hz": round(rate, 3),
        "clean_fps": n / clean_s, "median_savgol_fps": n / msg_s, "one_euro_fps": n / euro_s,
        "clean_over_median_savgol": clean_s / msg_s, "clean_over_one_euro": clean_s / euro_s,
        "clean_cpu_s": clean_s, "median_savgol_cpu_s": msg_s, "one_euro_cpu_s": euro_s,
        "clean_minor_page_faults": minor_page_faults(lambda: clean_recording(motion)),  # one more, untimed
    }
    if reference:
        ref_s = reference_cpu_seconds(motion)
        row.update(clean_numpy_reference_fps=n / ref_s, kernel_speedup=ref_s / clean_s)
    met = row["clean_fps"] >= TARGET_FPS and row["clean_over_median_savgol"] <= TARGET_RATIO
    row["targets_met"] = bool(met) if targets else None  # None: no target for this input
    return row


def _numba_version() -> str | None:
    try:
        import numba
    except ImportError:
        return None
    return numba.__version__


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="the shared data folder")
    ap.add_argument("--kinect-frames", type=int, default=10_000, help="frames of the looped Kinect v2 take")
    ap.add_argument("--bvh-frames", type=int, default=None, help="frames of the 120 Hz BVH take (default: all)")
    ap.add_argument("--c3d-frames", type=int, default=None, help="frames of the C3D marker take (default: all)")
    ap.add_argument("--repeats", type=int, default=3, help="runs of the clean and of each filter (best CPU time kept)")
    ap.add_argument("--quick", action="store_true",
                    help="2,000 Kinect, 600 BVH and 600 C3D frames (about a tenth of the time)")
    ap.add_argument("--reference", action="store_true",
                    help="also time the clean with the compiled kernels off (numpy references), same run")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "speed.json")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="also print the N functions with the most cumulative time in clean (cProfile, Kinect take)")
    args = ap.parse_args(argv)
    allocator_kept = keep_freed_memory()  # as the streamfix command does at start
    if args.quick:
        args.kinect_frames, args.bvh_frames, args.c3d_frames = 2_000, 600, 600
    kinect_files = sorted((args.data / "kinect_v2").glob("*.csv"))
    bvh_files = [args.data / "cmu_bvh" / n for n in ("131_01.bvh", "131_02.bvh")]
    c3d_file = args.data / "c3d" / "03_rolling.c3d"
    missing = [str(p) for p in bvh_files + [c3d_file] if not p.is_file()] + ([] if kinect_files else [str(args.data / "kinect_v2")])
    if missing:
        print(f"bench_speed: data not found: {', '.join(missing)}", file=sys.stderr)
        return 2
    takes = {
        "kinect_v2 30 Hz (5 CSVs looped)": looped([read_motion(p) for p in kinect_files], args.kinect_frames),
        "CMU BVH 120 Hz (131_01 + 131_02)": looped([read_motion(p) for p in bvh_files], args.bvh_frames),
    }
    untargeted = {"C3D markers (03_rolling, gaps)": looped([read_motion(c3d_file)], args.c3d_frames)}
    rows = []
    for name, motion in {**takes, **untargeted}.items():
        print(f"timing {name}: {motion.n_frames} frames ...", file=sys.stderr, flush=True)
        rows.append(measure(name, motion, args.repeats, args.reference, targets=name in takes))

    header = f"{'input':36s} {'frames':>6s} {'clean fps':>10s} {'med+SG fps':>11s} {'1euro fps':>10s} {'clean/medSG':>11s} {'clean/1euro':>11s}  target"
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['input']:36s} {r['frames']:6d} {r['clean_fps']:10.0f} {r['median_savgol_fps']:11.0f} "
              f"{r['one_euro_fps']:10.0f} {r['clean_over_median_savgol']:10.1f}x {r['clean_over_one_euro']:10.1f}x  "
              f"{'-' if r['targets_met'] is None else 'met' if r['targets_met'] else 'MISSED'}")
    for r in rows:
        if "kernel_speedup" in r:
            print(f"{r['input']:36s} numpy references: {r['clean_numpy_reference_fps']:.0f} frames/s; "
                  f"compiled kernels {r['kernel_speedup']:.2f}x faster (same run)")
    print(f"targets: clean >= {TARGET_FPS:.0f} frames/s of CPU time and <= {TARGET_RATIO:.0f}x median+Savitzky-Golay")
    faults = [f"{r['input']} {r['clean_minor_page_faults']}" for r in rows if r["clean_minor_page_faults"] is not None]
    if faults:
        print("minor page faults in one clean (memory the allocator gave back, mapped again): " + "; ".join(faults))
    if args.profile:  # where the time goes (after the timed runs: the profiler's overhead is not in the table)
        import cProfile
        import pstats

        profiler = cProfile.Profile()
        profiler.runcall(clean_recording, next(iter(takes.values())))
        pstats.Stats(profiler).sort_stats("cumulative").print_stats(args.profile)
    doc = {
        "benchmark": "bench_speed", "quick": args.quick,
        "targets": {"clean_fps_min": TARGET_FPS, "clean_over_median_savgol_max": TARGET_RATIO},
        "cpu": platform.processor() or platform.machine(), "python": platform.python_version(),
        "numba": _numba_version(), "kernels_compiled": kernels.COMPILED, "keep_freed_memory": allocator_kept,
        "rows": rows, "all_targets_met": all(r["targets_met"] is not False for r in rows),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0 if doc["all_targets_met"] else 1


if __name__ == "__main__":
    sys.exit(main())
