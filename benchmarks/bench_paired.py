"""Paired recordings (issue 8): every method against optical motion capture; exits 1 on a missed bar.

Runs :mod:`streamfix.evaluation.paired` on the whole trustworthy UI-PRMD subset (Kinect v1
+ Vicon) and the KERAAL take(s) (Kinect v2 + Vicon) in ``../shared/data/paired``, prints
one table per dataset and body region, and writes ``benchmarks/results/paired.json``
(records, bars, run details) and ``benchmarks/results/paired.md`` (the tables and bars).

Bars (issue 8; "debiased" = each joint's mean offset removed), for the ``streamfix`` method
(what ``streamfix clean`` writes) and again for ``streamfix_serve`` (``serve``'s ``clean``
topic), each method's seam at its own schedule's window hand-overs:

* UI-PRMD, upper body and lower body each: debiased mean error <= 0.9x the input's and
  lower than every baseline's;
* UI-PRMD, all joints: debiased p95 <= 0.85x the input's; output jitter <= 2.5x the
  reference's;
* KERAAL, all joints: debiased mean and p95 <= 0.9x the input's;
* both datasets, all joints: seam ratio (second difference on the frames next to a
  window hand-over / other frames) <= 1.1.

The same bars are also reported per UI-PRMD person, each pooled over that person's takes only
(:func:`person_bars`; printed and written as ``per_person``, not counted as bars): the same
checks run on people kept back, and the spread over the shared data's six people is the
estimate of where those land.

Also reported, not a bar (:func:`move_against_truth`): how far each engine method moves the
sensor's tracked joints beside median+Savitzky-Golay, and its debiased error with each take's
move scaled down to issue 8's real-Kinect bar on that move (checked by ``bench_accuracy.py`` on
Kinect files that have no truth): whether the truth agrees with that bar.

``streamfix_live`` (serve's causal ``live`` topic, no lookahead) is in the tables beside the
causal filters (One Euro, Holt) but has no bar: it is what a user sees at once, before the
window's fixes arrive on ``clean``.

Baselines are the methods run other than ``input`` and ``streamfix*`` (a whole-take solve,
``streamfix_whole``, is not a baseline); a method the
registry does not know is skipped with a warning. Takes run in ``--workers`` processes
(default and at most 2).

Usage: ``python benchmarks/bench_paired.py [--limit N] [--workers N] [--methods a,b,...] [--out DIR]``
(``--limit`` is for quick runs: it writes nothing unless ``--out`` is given).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PAIRED = (ROOT / ".." / "shared" / "data" / "paired").resolve()

from streamfix.cli.evaluate import _clean  # noqa: E402
from streamfix.evaluation.kinect import TRACKED_MOVE_BAR  # noqa: E402
from streamfix.evaluation.paired import DEFAULT_METHODS, print_paired_table, run_paired  # noqa: E402
from streamfix.evaluation.registry import CLEAN_METHODS  # noqa: E402

UIPRMD_MEAN_X_INPUT = 0.9
UIPRMD_P95_X_INPUT = 0.85
UIPRMD_JITTER_X_REFERENCE = 2.5
KERAAL_X_INPUT = 0.9
SEAM_MAX = 1.1
MAX_WORKERS = 2


def _get(records: list[dict], dataset: str, method: str, region: str) -> dict | None:
    return next((r for r in records if (r["dataset"], r["method"], r["region"]) == (dataset, method, region)), None)


def check_bars(records: list[dict], method: str = "streamfix") -> list[dict]:
    """``[{bar, value, target, ok}]`` for the issue-8 bars on paired data, for ``method``
    (``streamfix``: what ``clean`` writes; ``streamfix_serve``: serve's clean topic)."""
    bars: list[dict] = []

    def bar(name: str, value, target: float, ok: bool | None = None) -> None:
        if ok is None:
            ok = value is not None and value <= target
        bars.append({"bar": name, "value": value, "target": target, "ok": bool(ok)})

    def rel(dataset, region, key):
        s, i = _get(records, dataset, method, region), _get(records, dataset, "input", region)
        if s is None or i is None or s[key] is None or not i[key]:
            return None
        return s[key] / i[key]

    datasets = list(dict.fromkeys(r["dataset"] for r in records))
    if "uiprmd" in datasets:
        for region in ("upper", "lower"):
            bar(f"uiprmd {region}: {method} debiased mean / input", rel("uiprmd", region, "debiased_mean_m"),
                UIPRMD_MEAN_X_INPUT)
            s = _get(records, "uiprmd", method, region)
            others = [r for r in records if r["dataset"] == "uiprmd" and r["region"] == region
                      and r["method"] != "input" and not r["method"].startswith("streamfix")]
            best = min(others, key=lambda r: r["debiased_mean_m"], default=None)
            if best is not None:
                value = None if s is None else s["debiased_mean_m"] / best["debiased_mean_m"]
                bars.append({"bar": f"uiprmd {region}: {method} debiased mean / best baseline ({best['method']})",
                             "value": value, "target": 1.0, "ok": value is not None and value < 1.0})
        bar(f"uiprmd all: {method} debiased p95 / input", rel("uiprmd", "all", "debiased_p95_m"), UIPRMD_P95_X_INPUT)
        s = _get(records, "uiprmd", method, "all")
        bar(f"uiprmd all: {method} jitter / reference", None if s is None else s["jitter_ratio"],
            UIPRMD_JITTER_X_REFERENCE)
    if "keraal" in datasets:
        bar(f"keraal all: {method} debiased mean / input", rel("keraal", "all", "debiased_mean_m"), KERAAL_X_INPUT)
        bar(f"keraal all: {method} debiased p95 / input", rel("keraal", "all", "debiased_p95_m"), KERAAL_X_INPUT)
    for dataset in datasets:
        s = _get(records, dataset, method, "all")
        if s is not None and s.get("seam_frames") == 0:  # every take was one window: no hand-over to show
            bar(f"{dataset} all: {method} seam ratio (no window hand-over inside any take)", None, SEAM_MAX, ok=True)
        else:
            bar(f"{dataset} all: {method} seam ratio", None if s is None else s["seam_ratio"], SEAM_MAX)
    return bars


def person_bars(records: list[dict]) -> list[dict]:
    """``[{person, method, takes, bar, value, target, ok}]``: :func:`check_bars` on each person's
    own records (``run_paired(by_person=True)``), for each engine method.

    Not bars of their own (the issue's are on the pooled data): the spread over the shared
    data's people is the estimate of where people kept back will land, so a pooled value
    that holds while some people miss it holds with little room."""
    rows = []
    for person in sorted({r["person"] for r in records}):
        mine = [r for r in records if r["person"] == person]
        for method in CLEAN_METHODS:
            if any(r["method"] == method for r in mine):
                takes = next(r["n_takes"] for r in mine if r["method"] == method)
                rows += [{"person": person, "method": method, "takes": takes, **b} for b in check_bars(mine, method)
                         if "seam" not in b["bar"]]
    return rows


def print_person_bars(rows: list[dict], out=None) -> None:
    """One line per (person, method): each bar's value, ``!`` where the person misses it."""
    out = sys.stdout if out is None else out
    lines: dict[tuple, list[str]] = {}
    for r in rows:
        name = r["bar"].replace("uiprmd ", "").replace(f"{r['method']} ", "")  # e.g. "upper: debiased mean / input"
        v = "-" if r["value"] is None else f"{r['value']:.3f}"
        lines.setdefault((r["person"], r["method"], r["takes"]), []).append(f"{name} {v}{'' if r['ok'] else '!'}")
    for (person, method, takes), cells in lines.items():
        print(f"  {person:<5} {method:<16} {takes:>4} takes  " + "; ".join(cells), file=out)


def temporal_floor(records: list[dict]) -> list[dict]:
    """Per dataset and region: the input's debiased error below 3 Hz over its whole debiased error.

    No zero-lag temporal filter gets below this ratio (``debiased_slow_m`` of ``input``,
    :func:`streamfix.core.reference_metrics.slow_error_norm`); only replacing what the sensor
    has wrong does. Read it next to the ``x input`` bars: a bar below it asks for more than
    smoothing.
    """
    rows = []
    for r in records:
        if r["method"] == "input" and r.get("debiased_slow_m") is not None and r["debiased_mean_m"]:
            rows.append({"dataset": r["dataset"], "region": r["region"], "slow_m": r["debiased_slow_m"],
                         "debiased_m": r["debiased_mean_m"], "x_input": r["debiased_slow_m"] / r["debiased_mean_m"]})
    return rows


def move_against_truth(records: list[dict]) -> list[dict]:
    """Per dataset and engine method (all joints): how far it moves the sensor's tracked joints
    beside median+Savitzky-Golay, and what its debiased error becomes with each take's move
    scaled down to issue 8's real-Kinect bar (TRACKED_MOVE_BAR x median_savgol's).

    Why: that bar is checked on Kinect files without a truth; here the truth says whether the
    move it caps makes the output more or less accurate (not a bar: a measurement of one).
    """
    rows = []
    for r in records:
        if r["region"] != "all" or r.get("debiased_at_move_bar_m") is None:
            continue
        msg = _get(records, r["dataset"], "median_savgol", "all")
        inp = _get(records, r["dataset"], "input", "all")
        if msg is None or not msg.get("move_m") or inp is None:
            continue
        rows.append({"dataset": r["dataset"], "method": r["method"], "move_m": r["move_m"],
                     "move_x_median_savgol": r["move_m"] / msg["move_m"], "debiased_m": r["debiased_mean_m"],
                     "debiased_at_bar_m": r["debiased_at_move_bar_m"], "scale": r["move_bar_scale"],
                     "median_savgol_debiased_m": msg["debiased_mean_m"], "input_debiased_m": inp["debiased_mean_m"]})
    return rows


def print_move_against_truth(rows: list[dict], out=None) -> None:
    out = sys.stdout if out is None else out
    print(f"  {'dataset':<8} {'method':<16} {'moved mm':>9} {'x med+SG':>9} {'debiased mm':>12} "
          f"{'at the bar':>11} {'scale':>6} {'med+SG mm':>10} {'input mm':>9}", file=out)
    for m in rows:
        print(f"  {m['dataset']:<8} {m['method']:<16} {m['move_m'] * 1e3:9.1f} {m['move_x_median_savgol']:9.2f} "
              f"{m['debiased_m'] * 1e3:12.1f} {m['debiased_at_bar_m'] * 1e3:11.1f} {m['scale']:6.2f} "
              f"{m['median_savgol_debiased_m'] * 1e3:10.1f} {m['input_debiased_m'] * 1e3:9.1f}", file=out)


MOVE_HEADING = (f"the sensor's tracked joints moved, beside median+Savitzky-Golay, and the debiased error with each "
                f"take's move scaled down to the real-Kinect bar ({TRACKED_MOVE_BAR:g}x median+SG's; not a bar here):")


def _git_commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def _markdown(records: list[dict], bars: list[dict], info: dict, floor: list[dict], people: list[dict],
              moves: list[dict] = ()) -> str:
    import io

    buf = io.StringIO()
    print_paired_table(records, out=buf)
    lines = [
        "# Paired recordings: methods against optical motion capture",
        "",
        f"Written by `benchmarks/bench_paired.py` on {info['date']} (commit {info['commit']}); "
        f"{info['seconds']:.0f} s with {info['workers']} workers. Errors in mm; `x input` is the "
        "debiased mean / p95 relative to the raw sensor; `jitter/ref` the output's mean second "
        "difference over the reference's; `seam` the second difference on window hand-over frames "
        "over the other frames within a hop of them; `<3 Hz mm` the mean of the debiased error's part below 3 Hz. "
        "Definitions: `streamfix/evaluation/paired.py`."
        + (f" Engine prior: `{info['prior']}`." if info.get("prior", "shipped") != "shipped" else ""),
        "",
        "```",
        buf.getvalue().strip("\n"),
        "```",
        "",
        "| bar | value | target | |",
        "| --- | --- | --- | --- |",
    ]
    for b in bars:
        v = "-" if b["value"] is None else f"{b['value']:.3f}"
        lines.append(f"| {b['bar']} | {v} | {b['target']:g} | {'ok' if b['ok'] else 'MISSED'} |")
    if people:
        pbuf = io.StringIO()
        print_person_bars(people, out=pbuf)
        lines += ["", "The same bars per person, each pooled over that person's takes only (not bars themselves: "
                  "the spread says how much room the pooled values leave for people kept back; `!` = this person "
                  "misses it):", "", "```", pbuf.getvalue().rstrip("\n"), "```"]
    lines += ["", "The input's error below 3 Hz, which no zero-lag temporal filter removes (`temporal_floor`):", "",
              "| dataset | region | input debiased mm | below 3 Hz mm | x input |", "| --- | --- | --- | --- | --- |"]
    for f in floor:
        lines.append(f"| {f['dataset']} | {f['region']} | {f['debiased_m'] * 1e3:.1f} | {f['slow_m'] * 1e3:.1f} | "
                     f"{f['x_input']:.3f} |")
    if moves:
        mbuf = io.StringIO()
        print_move_against_truth(moves, out=mbuf)
        lines += ["", MOVE_HEADING[0].upper() + MOVE_HEADING[1:] + " (`move_against_truth`)", "", "```",
                  mbuf.getvalue().rstrip("\n"), "```"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=None, metavar="N", help="at most N repetitions per dataset")
    ap.add_argument("--workers", type=int, default=2, help="processes over repetitions (default 2)")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS), help="comma-separated method names")
    ap.add_argument("--out", type=Path, default=None,
                    help="results directory (default benchmarks/results; a --limit run writes only with --out)")
    ap.add_argument("--prior", type=Path, default=None, metavar="PATH",
                    help="score the engine with this prior (a card or its directory, as serve/clean --prior) instead "
                         "of the shipped one; writes only with --out")
    args = ap.parse_args(argv)
    if args.prior is not None:
        from streamfix.prior.runtime import set_default_prior

        try:
            set_default_prior(args.prior)  # the worker processes are forked after this: they inherit it
        except (OSError, ValueError) as exc:
            ap.error(f"--prior {args.prior}: {exc}")
    if not 1 <= args.workers <= MAX_WORKERS:
        ap.error(f"--workers must be 1..{MAX_WORKERS} (the benchmark machine is shared), got {args.workers}")
    out_dir = args.out if args.out is not None else (None if args.limit or args.prior else ROOT / "benchmarks" / "results")
    methods = [m for m in args.methods.split(",") if m]

    def progress(done: int, total: int) -> None:
        if done == total or done % 50 == 0:
            print(f"  {done}/{total} takes", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        every = run_paired([PAIRED], methods=methods, subset="trustworthy", limit=args.limit,
                           workers=args.workers, progress=progress, by_person=True)
    seconds = time.perf_counter() - t0
    skipped = [str(w.message) for w in caught if "skipping method" in str(w.message)]
    for msg in skipped:
        print(f"warning: {msg}", file=sys.stderr)
    records = [r for r in every if "person" not in r]
    print_paired_table(records)
    bars = [b for m in CLEAN_METHODS if any(r["method"] == m for r in records)
            for b in check_bars(records, m)]
    people = person_bars([r for r in every if "person" in r])
    print()
    for b in bars:
        v = "-" if b["value"] is None else f"{b['value']:.3f}"
        print(f"{'ok    ' if b['ok'] else 'MISSED'} {b['bar']}: {v} (target {b['target']:g})")
    if people:
        print("\nthe same bars per person (not bars themselves; ! = this person misses it):")
        print_person_bars(people)
    floor = temporal_floor(records)
    print("\nthe input's debiased error below 3 Hz (no zero-lag temporal filter removes it):")
    for f in floor:
        print(f"  {f['dataset']:<8s} {f['region']:<6s} {f['slow_m'] * 1e3:6.1f} of {f['debiased_m'] * 1e3:6.1f} mm "
              f"({f['x_input']:.3f}x input)")
    moves = move_against_truth(records)
    if moves:
        print("\n" + MOVE_HEADING)
        print_move_against_truth(moves)
    info = {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "commit": _git_commit(), "seconds": seconds, "workers": args.workers, "limit": args.limit,
            "methods": methods, "skipped": skipped, "data": str(PAIRED),
            "prior": str(args.prior) if args.prior is not None else "shipped"}
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        report = {"run": info, "bars": bars, "per_person": people, "temporal_floor": floor,
                  "move_against_truth": moves, "records": records}
        (out_dir / "paired.json").write_text(json.dumps(_clean(report), indent=1) + "\n")
        (out_dir / "paired.md").write_text(_markdown(records, bars, info, floor, people, moves))
        print(f"wrote {out_dir / 'paired.json'} and {out_dir / 'paired.md'}")
    missed = [b for b in bars if not b["ok"]]
    print(f"{len(bars) - len(missed)}/{len(bars)} bars met ({seconds:.0f} s)")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
