"""Accuracy bars of issue 2 for the default ``streamfix`` pipeline; exits 1 on a miss.

Runs, with fixed seeds:
* noise protocol on CMU 131_01 and 131_02 at 120 Hz (streamfix vs the paper's
  Table II totals 0.004/0.006/0.007/0.010 m at 5/10/15/20 %, 0.040 m at 80 %; ABE
  below ``wang``) and at 30 Hz (every method: streamfix below every baseline and
  below ``yang`` at every level; ABE below ``wang``);
* gap protocol at 30 Hz (gap_mae below linear and spline at 10 and 20 %);
* every Kinect v2 file (jitter cut >= median_savgol's, bone-length CV cut >= yang's), and
  issue 8's real-Kinect bars: tracked joints moved on average at most 1.5x what
  median_savgol moves them, bone-length CV at most 0.1x the input's, and no bone of an
  inferred limb more than 5 % from its left/right counterpart
  (:func:`streamfix.core.metrics.inferred_bone_asymmetry`). Beside them, what the geometry
  asks of any method: the least mean move of the tracked joints that puts every bone at
  its median length, or cuts every bone's length error to a tenth
  (:func:`streamfix.core.rigid_bound.least_shift_to_rigid`), over median_savgol's move; and
  the least move found for any output that meets the jitter and bone-CV bars together
  (:func:`streamfix.core.least_move.least_move_meeting_bars`, the whole take known at once):
  where that is above the move bar, no cleaner meets the three bars on the file.

Usage: ``python benchmarks/bench_accuracy.py [--seed N] [--json OUT]``. Writes
``benchmarks/results/accuracy.json`` (every record) and ``accuracy.md`` (what it printed).
``streamfix`` is the engine's clean output as ``streamfix clean`` writes it (the file
schedule, :meth:`~streamfix.streaming.engine.EngineConfig.for_files`); ``streamfix_whole`` the
whole-take function, printed beside it.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = (ROOT / ".." / "shared" / "data").resolve()

from streamfix.cli.evaluate import print_table  # noqa: E402
from streamfix.evaluation.kinect import TRACKED_MOVE_BAR, run_kinect  # noqa: E402
from streamfix.evaluation.noise_gaps import run_gaps, run_noise  # noqa: E402

TABLE_II = {5: 0.004, 10: 0.006, 15: 0.007, 20: 0.010, 80: 0.040}
BONE_CV_MAX = 0.1  # issue 8: x the input's bone-length CV
INFERRED_ASYMMETRY_MAX = 0.05  # issue 8: inferred limb's bone vs its mirror, fraction
BASELINES = ["input", "yang", "li", "wang", "one_euro", "holt", "savgol", "median_savgol", "linear", "spline"]


class _Tee:
    """Print to the terminal and keep a copy for the results file."""

    def __init__(self, stream) -> None:
        self.stream, self.lines = stream, []

    def write(self, text: str) -> int:
        self.lines.append(text)
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()


def main() -> int:
    tee = _Tee(sys.stdout)
    sys.stdout = tee
    try:
        return _main(tee)
    finally:
        sys.stdout = tee.stream


def _main(tee: _Tee) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "accuracy.json"),
                    help="write all records to this file (default benchmarks/results/accuracy.json); "
                         "what is printed goes beside it as .md")
    args = ap.parse_args()
    cmu = [str(DATA / "cmu_bvh" / f"{n}.bvh") for n in ("131_01", "131_02")]
    kinect = sorted(str(p) for p in (DATA / "kinect_v2").glob("*.csv"))
    t0 = time.perf_counter()
    recs = []
    recs += run_noise(cmu, rate_hz=120.0, levels=list(TABLE_II), seed=args.seed,
                      methods=["input", "streamfix", "wang", "median_savgol"])
    recs += run_noise(cmu, rate_hz=30.0, levels=list(TABLE_II), seed=args.seed,
                      methods=["streamfix", *BASELINES])
    recs += run_gaps(cmu, rate_hz=30.0, levels=[10, 20], seed=args.seed,
                     methods=["input", "streamfix", "linear", "spline"])
    recs += run_kinect(kinect, methods=["input", "streamfix", "yang", "median_savgol", "holt", "one_euro"],
                       least_move=True)
    elapsed = time.perf_counter() - t0
    print_table(recs)

    misses, checks = [], 0

    def check(ok: bool, what: str) -> None:
        nonlocal checks
        checks += 1
        if not ok:
            misses.append(what)

    def get(file, rate, protocol, level, method):
        return next(r for r in recs if r["file"] == file and r["rate_hz"] == rate and r["protocol"] == protocol
                    and r["level"] == level and r["method"] == method)

    print("\nbars")
    for f in cmu:
        name = Path(f).stem
        for lv, bar in TABLE_II.items():
            sf = get(f, 120.0, "noise", lv, "streamfix")
            wang = get(f, 120.0, "noise", lv, "wang")
            check(sf["aje_m"] <= bar, f"{name} 120 Hz {lv}%: AJE {sf['aje_m']:.4f} > {bar}")
            check(sf["abe_m"] < wang["abe_m"], f"{name} 120 Hz {lv}%: ABE {sf['abe_m']:.4f} >= wang {wang['abe_m']:.4f}")
            print(f"  {name} 120 Hz {lv:>2}%  AJE {sf['aje_m']:.4f} (bar {bar})  ABE {sf['abe_m']:.4f} (wang {wang['abe_m']:.4f})")
            sf30 = get(f, 30.0, "noise", lv, "streamfix")
            best = min(BASELINES, key=lambda m: get(f, 30.0, "noise", lv, m)["aje_m"])
            b_aje = get(f, 30.0, "noise", lv, best)["aje_m"]
            check(sf30["aje_m"] < b_aje, f"{name} 30 Hz {lv}%: AJE {sf30['aje_m']:.4f} >= {best} {b_aje:.4f}")
            w30 = get(f, 30.0, "noise", lv, "wang")["abe_m"]
            check(sf30["abe_m"] < w30, f"{name} 30 Hz {lv}%: ABE {sf30['abe_m']:.4f} >= wang {w30:.4f}")
            print(f"  {name}  30 Hz {lv:>2}%  AJE {sf30['aje_m']:.4f}  best baseline {best} {b_aje:.4f}  "
                  f"ratio {sf30['aje_m'] / b_aje:.2f}")
        for lv in (10, 20):
            sf = get(f, 30.0, "gaps", lv, "streamfix")["gap_mae_m"]
            lin = get(f, 30.0, "gaps", lv, "linear")["gap_mae_m"]
            spl = get(f, 30.0, "gaps", lv, "spline")["gap_mae_m"]
            check(sf < min(lin, spl), f"{name} gaps {lv}%: gap MAE {sf:.4f} >= linear {lin:.4f}/spline {spl:.4f}")
            print(f"  {name}  30 Hz gaps {lv}%  gap MAE {sf:.4f}  linear {lin:.4f}  spline {spl:.4f}")
    for f in kinect:
        rs = {r["method"]: r for r in recs if r["file"] == f}
        sf, ms, ya = rs["streamfix"], rs["median_savgol"], rs["yang"]
        check(sf["jitter_ratio"] <= ms["jitter_ratio"],
              f"{Path(f).name}: jitter ratio {sf['jitter_ratio']:.3f} > median_savgol {ms['jitter_ratio']:.3f}")
        check(sf["bone_cv_ratio"] <= ya["bone_cv_ratio"],
              f"{Path(f).name}: bone CV ratio {sf['bone_cv_ratio']:.3f} > yang {ya['bone_cv_ratio']:.3f}")
        print(f"  {Path(f).name:<26} jitter after/before {sf['jitter_ratio']:.3f} (median_savgol "
              f"{ms['jitter_ratio']:.3f})  bone CV after/before {sf['bone_cv_ratio']:.3f} (yang {ya['bone_cv_ratio']:.3f})")
        # issue 8, real Kinect CSVs: tracked joints barely moved, bones steady, inferred limbs symmetric
        moved = sf["tracked_shift_m"] / ms["tracked_shift_m"] if ms["tracked_shift_m"] else float("inf")
        check(moved <= TRACKED_MOVE_BAR, f"{Path(f).name}: tracked joints moved {moved:.2f}x median_savgol's "
                                          f"(bar {TRACKED_MOVE_BAR})")
        check(sf["bone_cv_ratio"] <= BONE_CV_MAX, f"{Path(f).name}: bone CV ratio {sf['bone_cv_ratio']:.3f} > {BONE_CV_MAX}")
        asym = sf.get("inferred_asymmetry")
        if asym is not None:
            check(asym <= INFERRED_ASYMMETRY_MAX,
                  f"{Path(f).name}: an inferred limb's bone is {100 * asym:.1f} % off its mirror (bar {100 * INFERRED_ASYMMETRY_MAX:.0f} %)")
        print(f"  {'':<26} tracked joints moved {moved:.2f}x median_savgol's (bar {TRACKED_MOVE_BAR})  bone CV "
              f"after/before {sf['bone_cv_ratio']:.3f} (bar {BONE_CV_MAX})  inferred limb vs mirror "
              + ("-" if asym is None else f"{100 * asym:.1f} %") + f" (bar {100 * INFERRED_ASYMMETRY_MAX:.0f} %)")
        if ms["tracked_shift_m"]:  # what the geometry asks of any method (streamfix.core.rigid_bound)
            print(f"  {'':<26} least move of tracked joints for bones at their median lengths "
                  f"{sf['rigid_shift_bound_m'] / ms['tracked_shift_m']:.2f}x median_savgol's, for every bone's "
                  f"length error cut to a tenth {sf['tenth_shift_bound_m'] / ms['tracked_shift_m']:.2f}x")
            if sf.get("least_move_m") is not None:  # streamfix.core.least_move
                print(f"  {'':<26} least move found for any output with jitter <= median_savgol's and bone CV "
                      f"<= {BONE_CV_MAX}x the input's: {sf['least_move_m'] / ms['tracked_shift_m']:.2f}x median_savgol's"
                      + ("" if sf["least_move_feasible"] else " (bars not reached)"))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(recs, indent=1, default=float))
    print(f"\n{checks - len(misses)}/{checks} bars held ({elapsed:.0f} s)")
    for m in misses:
        print(f"MISSED: {m}")
    if args.json:
        Path(args.json).with_suffix(".md").write_text("# bench_accuracy\n\n```\n" + "".join(tee.lines) + "```\n")
    return 1 if misses else 0


if __name__ == "__main__":
    sys.exit(main())
