"""The sensor protocol (issue 8) on every CMU and Xia take x 3 seeds; exits 1 on a missed bar.

Runs :func:`streamfix.evaluation.sensor.run_sensor` (realistic sensor errors on mocap
ground truth, Kinect v2 joints at 30 Hz; error model in ``docs/SENSOR_ERRORS.md``) on
``../shared/data/cmu_bvh/*.bvh`` and ``../shared/data/xia_bvh/*.bvh``, one take per job
on at most 2 worker processes, pools the records per error kind and method
(:func:`~streamfix.evaluation.sensor.summarise`), prints the tables and writes
``benchmarks/results/sensor.json`` (pooled and per-take summaries, bars; every record
with ``--records``) and ``sensor.md``.

Bars (issue 8, "Sensor protocol" and "No seam"), for the ``streamfix`` method (what
``streamfix clean`` writes) and again for ``streamfix_serve`` (``serve``'s ``clean`` topic);
each method's seam is measured at its own schedule's window hand-overs:

* below the best baseline's mean joint error (all joint-frames) on every error kind and
  on ``mix`` (baselines: every method but ``input`` and ``streamfix*``; a baseline that
  leaves joint-frames missing is not eligible on that kind);
* collateral damage (error on uncorrupted joint-frames) no larger than
  ``median_savgol``'s on every kind that has such frames;
* on swapped joint-frames at most 0.3x the input's error; on frozen/drifting limbs
  (``freeze``, flagged inferred) at most 0.5x; on joints thrown along their camera ray
  (``depth``, its parameters assumed: ``docs/SENSOR_ERRORS.md``) at most 0.1x, throws in a
  stream's first second included;
* ``flagged`` (right limbs flagged inferred: a hazard, not an error, so no "below the best
  baseline" bar; the input is exact there): error on the flagged joint-frames no larger
  than ``median_savgol``'s there, i.e. a cleaner that questions inferred limbs may not
  damage right ones more than a plain smoother does;
* seam ratio (jitter next to window hand-overs / within a hop of them, pooled over all kinds)
  at most 1.1, where the method's schedule hands over within a take (``serve``'s does; every
  take here fits in one file window, so ``streamfix``'s hand-overs are checked on a longer
  take by ``tests/test_streaming_offline.py``).

``streamfix_live`` (serve's causal ``live`` topic) is in the tables with no bar, beside the
causal filters (One Euro, Holt).

Also written, with no bar: per error kind, in how many takes x seeds the engine beats the
baseline its pooled bar names, and the worst take (:func:`per_take`): the pooled means weigh
takes by their frames, and the short Xia takes (1-3 s, shorter than a ``clean`` window) are
where the engine is weakest. And the corrupted joint-frames' means on only the takes the
engine's prior did not train on (:func:`prior_held_out_takes`, from its model card): its
training data include the other CMU and Xia takes, which flatters the pooled figures where the
prior fills a limb.

Usage: ``python3 benchmarks/bench_sensor.py [--seeds 3] [--workers 2] [--files F ...]``
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = (ROOT / ".." / "shared" / "data").resolve()
RESULTS = ROOT / "benchmarks" / "results"

from streamfix.evaluation.registry import CLEAN_METHODS, ENGINE_SCHEDULES  # noqa: E402
from streamfix.evaluation.sensor import SCORED_KINDS, run_sensor, summarise  # noqa: E402

SWAP_MAX_RATIO = 0.3
FREEZE_MAX_RATIO = 0.5
DEPTH_MAX_RATIO = 0.1
SEAM_MAX_RATIO = 1.1
NOT_BASELINES = ("input", *ENGINE_SCHEDULES)  # the engine: what `clean` writes, serve's clean and live topics
HAZARDS = ("flagged",)  # the input is right there: scored for damage, not against the baselines
GAP_ONLY = ("linear", "spline")  # pass observed samples through: a baseline only where the input has gaps


def _job(args: tuple[str, int]) -> list[dict]:
    path, seeds = args
    import warnings

    warnings.simplefilter("ignore", UserWarning)  # missing methods are reported once, below
    return run_sensor([path], seed=0, n_seeds=seeds)


def _shown(path: Path) -> str:
    """A take's name in the results: ``../shared/data/...`` for the shared recordings."""
    p = Path(path).resolve()
    return f"../shared/data/{p.relative_to(DATA)}" if p.is_relative_to(DATA) else str(path)


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1000:.1f}"


def check_bars(summary: dict, seam_ratio: float | None, method: str = "streamfix") -> list[dict]:
    """Every bar for ``method`` (``streamfix`` or ``streamfix_serve``) as {bar, kind, value, target, ok}."""
    bars = []
    tag = "" if method == "streamfix" else f"{method}: "
    for kind in SCORED_KINDS:
        per = summary.get(kind, {})
        sf = per.get(method)
        if sf is None:
            continue
        has_gaps = per.get("input", {}).get("unfilled", 0.0) > 0
        base = {m: v["err_m"] for m, v in per.items()
                if m not in NOT_BASELINES and v["err_m"] is not None and (has_gaps or m not in GAP_ONLY)}
        ms = per.get("median_savgol")
        if kind in HAZARDS:
            if ms and ms["err_corrupted_m"] is not None and sf["err_corrupted_m"] is not None:
                bars.append({"bar": f"{tag}flagged joint-frames <= median_savgol's", "kind": kind,
                             "value": sf["err_corrupted_m"], "target": ms["err_corrupted_m"],
                             "ok": sf["err_corrupted_m"] <= ms["err_corrupted_m"]})
        elif base and sf["err_m"] is not None:
            best = min(base, key=base.get)
            bars.append({"bar": f"{method} < best baseline ({best}), all joint-frames", "kind": kind,
                         "value": sf["err_m"], "target": base[best], "ok": sf["err_m"] < base[best],
                         "method": method, "baseline": best})
        if ms and ms["err_clean_m"] is not None and sf["err_clean_m"] is not None:
            bars.append({"bar": f"{tag}collateral damage <= median_savgol's", "kind": kind, "value": sf["err_clean_m"],
                         "target": ms["err_clean_m"], "ok": sf["err_clean_m"] <= ms["err_clean_m"]})
        inp = per.get("input")
        for k, ratio in (("swap", SWAP_MAX_RATIO), ("freeze", FREEZE_MAX_RATIO), ("depth", DEPTH_MAX_RATIO)):
            if kind == k and inp and inp["err_corrupted_m"] and sf["err_corrupted_m"] is not None:
                target = ratio * inp["err_corrupted_m"]
                bars.append({"bar": f"{tag}corrupted joint-frames <= {ratio}x input", "kind": kind,
                             "value": sf["err_corrupted_m"], "target": target, "ok": sf["err_corrupted_m"] <= target})
    if seam_ratio is not None:
        bars.append({"bar": f"{tag}seam ratio <= {SEAM_MAX_RATIO}", "kind": "all", "value": seam_ratio,
                     "target": SEAM_MAX_RATIO, "ok": seam_ratio <= SEAM_MAX_RATIO})
    return bars


def per_take(records: list[dict], bars: list[dict]) -> list[dict]:
    """For each "below the best baseline" bar: in how many takes x seeds the engine's mean
    error on all joint-frames is below that baseline's, and the worst ratio (take, seed).

    Why: the bars pool joint-frames, so long takes outweigh short ones; a take shorter than
    a window (a stream's first seconds) can lose to the baseline while the pool wins.
    Informational (no bar): the issue's bars are on the pooled means."""
    err = {(r["kind"], r["method"], r["file"], r["seed"]): r["err_m"] for r in records
           if r.get("protocol") == "sensor" and r.get("err_m") is not None and np.isfinite(r["err_m"])}
    rows = []
    for b in bars:
        if "baseline" not in b:
            continue
        kind, method, base = b["kind"], b["method"], b["baseline"]
        cases = sorted({(f, sd) for (k, m, f, sd) in err if k == kind and m == method and (k, base, f, sd) in err})
        if not cases:
            continue
        ratios = [err[(kind, method, f, sd)] / err[(kind, base, f, sd)] if err[(kind, base, f, sd)] > 0 else float("inf")
                  for f, sd in cases]
        worst = int(np.argmax(ratios))
        rows.append({"kind": kind, "method": method, "baseline": base, "cases": len(cases),
                     "wins": int(sum(r < 1.0 for r in ratios)), "worst_ratio": float(ratios[worst]),
                     "worst_take": _shown(Path(cases[worst][0])), "worst_seed": int(cases[worst][1])})
    return rows


def prior_held_out_takes(files: list[Path]) -> list[Path]:
    """The takes among ``files`` that the engine's prior did not train on (its model card's
    ``training.held_out``, matched by file stem). Why: the prior's training data include
    most of the CMU and Xia takes this protocol corrupts, so where the prior fills a limb
    (``dropout``, a released ``freeze``) the pooled figures include takes it has seen."""
    from streamfix.prior.runtime import load_default_prior

    try:
        held = set(load_default_prior().card.get("training", {}).get("held_out", ()))
    except (FileNotFoundError, ValueError):  # no prior: the engine fills nothing from one
        return []
    return [f for f in files if Path(f).stem in held]


def markdown(summary: dict, seams: dict, bars: list[dict], meta: dict, takes: list[dict] = (),
             unseen: dict | None = None) -> str:
    methods = list(dict.fromkeys(m for per in summary.values() for m in per))
    out = [f"# Sensor protocol ({meta['takes']} takes x {meta['seeds']} seeds, {meta['rate_hz']:g} Hz)", "",
           "Written by `benchmarks/bench_sensor.py`; error model in `docs/SENSOR_ERRORS.md`. "
           "Mean joint error in mm, pooled over takes and seeds.", ""]
    if meta.get("prior", "shipped") != "shipped":
        out += [f"Engine prior: `{meta['prior']}`.", ""]
    for key, title in (("err_m", "all joint-frames"), ("err_corrupted_m", "corrupted joint-frames"),
                       ("err_clean_m", "uncorrupted joint-frames (collateral damage)")):
        out += [f"## {title}", "", "| kind | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
        for kind in SCORED_KINDS:
            if kind in summary:
                out.append(f"| {kind} | " + " | ".join(_mm(summary[kind].get(m, {}).get(key)) for m in methods) + " |")
        out.append("")
    out += ["## seam ratio (all kinds)", "", "| " + " | ".join(methods) + " |", "|---" * len(methods) + "|",
            "| " + " | ".join("-" if seams.get(m) is None else f"{seams[m]:.3f}" for m in methods) + " |", "",
            "## bars", "", "| bar | kind | value | target | ok |", "|---|---|---|---|---|"]
    for b in bars:
        fmt = (lambda v: f"{v:.3f}") if "seam" in b["bar"] else _mm
        out.append(f"| {b['bar']} | {b['kind']} | {fmt(b['value'])} | {fmt(b['target'])} | {'yes' if b['ok'] else 'NO'} |")
    if takes:
        out += ["", "## takes x seeds below the bar's baseline (informational: the bars are on pooled means)", "",
                "| kind | method | baseline | won | worst ratio | worst take (seed) |", "|---|---|---|---|---|---|"]
        for t in takes:
            out.append(f"| {t['kind']} | {t['method']} | {t['baseline']} | {t['wins']}/{t['cases']} | "
                       f"{t['worst_ratio']:.3f} | {t['worst_take']} ({t['worst_seed']}) |")
    if unseen and unseen.get("summary"):
        out += ["", "## corrupted joint-frames on the takes the engine's prior did not train on (informational)", "",
                (f"Takes: {', '.join(unseen['takes'])}. The prior's training data include the other takes above "
                 "(its model card), so on the kinds it fills a limb for (dropout, a released freeze) the pooled "
                 "tables include takes it has seen. The same mean, on these takes only:"), "",
                "| kind | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
        for kind in SCORED_KINDS:
            if kind in unseen["summary"]:
                per = unseen["summary"][kind]
                out.append(f"| {kind} | " + " | ".join(_mm(per.get(m, {}).get("err_corrupted_m")) for m in methods) + " |")
    if meta.get("missing_methods"):
        out += ["", f"Methods not in this registry (skipped): {', '.join(meta['missing_methods'])}."]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    from streamfix.evaluation.registry import METHODS
    from streamfix.evaluation.sensor import DEFAULT_METHODS, DEFAULT_RATE_HZ, format_table

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=3, help="seeds per take and kind (default 3)")
    p.add_argument("--workers", type=int, default=2, help="worker processes (default 2, the most allowed)")
    p.add_argument("--files", nargs="+", type=Path, default=None, help="BVH takes (default: all CMU and Xia takes)")
    p.add_argument("--out", type=Path, default=None,
                   help="results folder (default benchmarks/results; a --prior run writes only with --out)")
    p.add_argument("--records", action="store_true", help="also write every record into sensor.json (large)")
    p.add_argument("--prior", type=Path, default=None, metavar="PATH",
                   help="score the engine with this prior (a card or its directory, as serve/clean --prior) "
                        "instead of the shipped one")
    args = p.parse_args(argv)
    init = {}  # worker processes load the --prior too (whatever their start method)
    if args.prior is not None:
        from streamfix.prior.runtime import set_default_prior

        try:
            set_default_prior(args.prior)  # a bad path fails here, before any work
        except (OSError, ValueError) as exc:
            print(f"bench_sensor: --prior {args.prior}: {exc}", file=sys.stderr)
            return 2
        init = {"initializer": set_default_prior, "initargs": (str(args.prior),)}
    out_dir = args.out if args.out is not None else (None if args.prior is not None else RESULTS)
    files = args.files or sorted((DATA / "cmu_bvh").glob("*.bvh")) + sorted((DATA / "xia_bvh").glob("*.bvh"))
    if not files:
        print(f"bench_sensor: no BVH takes found under {DATA}", file=sys.stderr)
        return 1
    missing = [m for m in DEFAULT_METHODS if m not in METHODS]
    if missing:
        print(f"bench_sensor: methods not in this registry, skipped: {', '.join(missing)}", file=sys.stderr)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=max(1, min(args.workers, 2)), **init) as pool:
        records = [r for recs in pool.map(_job, [(str(f), args.seeds) for f in files]) for r in recs]
    wall = time.perf_counter() - t0
    summary = summarise(records)
    seams = {m: v["seam_ratio"] for m, v in summarise([dict(r, kind="all") for r in records])["all"].items()}
    bars = [b for m in CLEAN_METHODS if m in METHODS for b in check_bars(summary, seams.get(m), m)]
    meta = {"takes": len(files), "seeds": args.seeds, "rate_hz": DEFAULT_RATE_HZ, "wall_s": wall,
            "files": [_shown(f) for f in files], "missing_methods": missing,
            "prior": str(args.prior) if args.prior is not None else "shipped"}
    print(format_table(records))
    print("\nbars:")
    for b in bars:
        fmt = (lambda v: f"{v:.3f}") if "seam" in b["bar"] else (lambda v: f"{_mm(v)} mm")
        print(f"  {'ok  ' if b['ok'] else 'MISS'} {b['kind']:<8} {b['bar']}: {fmt(b['value'])} (target {fmt(b['target'])})")
    takes = per_take(records, bars)
    print("\ntakes x seeds below the bar's baseline (informational):")
    for t in takes:
        print(f"  {t['kind']:<8} {t['method']:<16} {t['wins']:>3}/{t['cases']:<3} vs {t['baseline']:<13} "
              f"worst {t['worst_ratio']:.3f} ({t['worst_take']}, seed {t['worst_seed']})")
    held = prior_held_out_takes(files)
    held_paths = {str(f) for f in held}  # the records name their take as it was passed
    unseen = {"takes": [_shown(f) for f in held], "summary": summarise([r for r in records if r["file"] in held_paths])}
    if held:
        print(f"\ncorrupted joint-frames (mm) on the takes the prior did not train on ({', '.join(f.stem for f in held)}):")
        for kind in SCORED_KINDS:
            per = unseen["summary"].get(kind, {})
            print(f"  {kind:<8} " + "  ".join(f"{m} {_mm(per.get(m, {}).get('err_corrupted_m'))}"
                                            for m in ("input", "median_savgol", *CLEAN_METHODS) if m in per))
    n_miss = sum(not b["ok"] for b in bars)
    if out_dir is None:
        print(f"\n{len(bars) - n_miss}/{len(bars)} bars met; {len(records)} records in {wall:.0f} s (not written: no --out)")
        return 1 if n_miss else 0
    out_dir.mkdir(parents=True, exist_ok=True)
    per_file = {_shown(f): summarise([r for r in records if r["file"] == str(f)]) for f in files}
    doc = {"meta": meta, "summary": summary, "seam_ratio": seams, "bars": bars, "per_take": takes, "per_file": per_file,
           "prior_unseen": unseen}
    if args.records:
        doc["records"] = records
    (out_dir / "sensor.json").write_text(json.dumps(doc, indent=1) + "\n")
    (out_dir / "sensor.md").write_text(markdown(summary, seams, bars, meta, takes, unseen))
    print(f"\n{len(bars) - n_miss}/{len(bars)} bars met; {len(records)} records in {wall:.0f} s; "
          f"wrote {out_dir / 'sensor.json'} and sensor.md")
    return 1 if n_miss else 0


if __name__ == "__main__":
    sys.exit(main())
