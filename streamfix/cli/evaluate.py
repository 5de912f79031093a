"""``streamfix eval FILE...``: the paper's protocols on readable files, as a table or JSON.

Protocols come from the modules of :mod:`streamfix.evaluation` (each exposes
``PROTOCOLS = {name: run}``); ``--protocol auto`` (default) runs ``kinect`` on Kinect v2
CSV files (no ground truth) and ``noise`` on everything else.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

from .options import add_list_argument, positive_number

HELP = "reproduce the paper's protocols (noise, gaps, ...) on files and score every method"

#: Protocols whose runner takes no corruption levels (``--levels`` is an error there).
_NO_LEVELS = ("kinect", "sensor", "paired")

#: What a ``--levels`` value is per protocol and its valid range, in the user's units (the
#: runners take %, or frames, and fail deep inside on a value out of range, e.g. noise's
#: ``fraction must be in [0, 1], got -0.05`` for ``--levels -5``).
_LEVEL_RANGES = {
    "noise": ("a % of coordinates given noise, 0 to 100", lambda v: 0 <= v <= 100),
    "gaps": ("a % of joint-frames missing, 0 to less than 100", lambda v: 0 <= v < 100),
    "occlusion": ("a % of joints dropped, 0 to 100", lambda v: 0 <= v <= 100),
    "long-gaps": ("a gap length in frames, 1 or more", lambda v: 1 <= v < math.inf),
    "blackout": ("a % of each window's frames removed, more than 0 up to 100", lambda v: 0 < v <= 100),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="*", metavar="FILE",
                        help="motion files (BVH, C3D, Kinect v2 CSV); for --protocol paired the paired "
                             "recordings' directory (default ../shared/data/paired)")
    parser.add_argument("--rate", type=positive_number("Hz"), default=None, metavar="HZ",
                        help="resample every file to HZ first (e.g. 30 for a Kinect's rate); default: native")
    parser.add_argument("--protocol", default="auto",
                        help="noise | gaps | kinect | occlusion | long-gaps | blackout | sensor | auto (default: "
                             "kinect for Kinect CSV, noise otherwise)")
    add_list_argument(parser, "--levels", type=float, metavar="LEVEL",
                      help="corruption levels, as 'a b' or 'a,b'; what a level is depends on the protocol: "
                           "noise = %% of coordinates given uniform +-0.25 m noise (default 5 10 15 20 80); "
                           "gaps = %% of joint-frames missing, in runs of 10-60 frames (default 10 20); "
                           "occlusion = %% of joints dropped (limb patterns are always added; default 25 50); "
                           "long-gaps = gap length in frames, 5 gaps each (default: the paper's length and count "
                           "sweeps); blackout = %% of each window's frames removed whole (default 5 to 30); "
                           "kinect, sensor and paired have no levels")
    parser.add_argument("--seed", type=int, default=0, help="seed of the corruption (default 0)")
    add_list_argument(parser, "--methods", metavar="NAME",
                      help="methods to score (default: all), as 'a b', 'a,b' or a repeated --methods")
    parser.add_argument("--json", action="store_true", help="print one JSON document (a list of records)")
    parser.add_argument("--subset", choices=("trustworthy", "all"), default=None,
                        help="paired protocol: UI-PRMD repetitions to score (default trustworthy, see its README)")
    parser.add_argument("--limit", type=int, default=None, metavar="N",
                        help="paired protocol: at most N repetitions per dataset, spread over the list (quick runs)")
    parser.add_argument("--progress", action="store_true",
                        help="draw the progress line on stderr even when it is not a terminal (default: only then)")
    parser.add_argument("--report", default=None, metavar="DIR",
                        help="also write DIR/<file>.html: plots of each file cleaned by the engine (streamfix report)")


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item") and getattr(value, "ndim", 1) == 0:  # numpy scalar
        return _clean(value.item())
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def _fmt(v, scale=1.0, digits=4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v * scale:.{digits}f}"


def print_table(records: list[dict], out=None) -> None:
    """Human-readable tables: one per (file, rate, protocol)."""
    out = sys.stdout if out is None else out
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in records:
        groups[(r["file"], r["rate_hz"], r["protocol"])].append(r)
    for (file, rate, protocol), recs in groups.items():
        print(f"\n{file} @ {rate:g} Hz, protocol {protocol}", file=out)
        methods = list(dict.fromkeys(r["method"] for r in recs))
        if protocol == "sensor":  # per error kind, not per level
            from ..evaluation.sensor import format_table

            print(format_table(recs), file=out)
            continue
        if protocol == "kinect":
            cols = [("jitter_ratio", "jitter after/before"), ("bone_cv_ratio", "bone CV after/before"),
                    ("inferred_shift_m", "inferred shift m"), ("inferred_bone_cv", "inferred bone CV")]
            print(f"{'method':<14}" + "".join(f"{title:>22}" for _, title in cols), file=out)
            for m in methods:
                r = next(x for x in recs if x["method"] == m)
                print(f"{m:<14}" + "".join(f"{_fmt(r.get(k)):>22}" for k, _ in cols), file=out)
            continue
        levels = sorted({r["level"] for r in recs})
        keys = [("aje_m", "AJE m"), ("abe_m", "ABE m")]
        if any(r.get("gap_mae_m") is not None for r in recs):
            keys.append(("gap_mae_m", "gap MAE m"))
        for key, title in keys:
            print(f"{title:<14}" + "".join(f"{lv:>9g}%" for lv in levels), file=out)
            for m in methods:
                row = []
                for lv in levels:
                    r = next((x for x in recs if x["method"] == m and x["level"] == lv), None)
                    row.append(_fmt(None if r is None else r.get(key)))
                print(f"  {m:<12}" + "".join(f"{c:>10}" for c in row), file=out)


def _accepts(fn, keyword: str) -> bool:
    """Protocol runners may predate a keyword (``methods``: ARCHITECTURE.md contract)."""
    import inspect

    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return True
    return keyword in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def _directory_message(path: str, protocol: str, protocols: dict) -> str:
    """Why a directory given as FILE is refused, and what it holds. Why: only a protocol that
    takes a directory (paired, its recordings' directory) reads one; any other wants the
    motion files themselves, and a reader would blame the directory's (missing) extension."""
    from ..io import READ_FORMATS

    try:
        found = sorted(p.name for p in Path(path).iterdir() if p.suffix.lower() in READ_FORMATS and p.is_file())
    except OSError as exc:
        found, holds = [], f"it cannot be listed ({exc.strerror or exc})"
    else:
        holds = (f"it holds {len(found)} motion file(s): {', '.join(found[:3])}{', ...' if len(found) > 3 else ''}"
                 f"; give them as FILE arguments, e.g. {Path(path) / ('*' + Path(found[0]).suffix)}" if found else
                 f"it holds no motion files ({', '.join(READ_FORMATS)})")
    readers = sorted(n for n, fn in protocols.items() if _accepts(fn, "subset"))
    takes = f" (only --protocol {', '.join(readers)} reads a directory)" if readers else ""
    return f"{path} is a directory, protocol {protocol} reads motion files{takes}: {holds}"


def run(args: argparse.Namespace) -> int:
    from ..evaluation.registry import ALL_METHODS, discover_protocols, is_kinect_file
    from .progress import ProgressLine

    protocols = discover_protocols()
    methods = None
    if args.methods:
        methods = list(args.methods)
        unknown = [m for m in methods if m not in ALL_METHODS]
        if unknown:
            print(f"streamfix eval: unknown method(s) {', '.join(unknown)}; expected some of: "
                  f"{', '.join(ALL_METHODS)}", file=sys.stderr)
            return 2
    plan: dict[str, list[str]] = defaultdict(list)
    if not args.files:
        if args.protocol not in protocols or not _accepts(protocols[args.protocol], "subset"):
            print(f"streamfix eval: protocol {args.protocol!r} needs FILE arguments (only paired "
                  f"recordings have a default directory)", file=sys.stderr)
            return 2
        plan[args.protocol] = []
    for f in args.files:
        name = args.protocol
        if name == "auto":
            name = "kinect" if is_kinect_file(f) else "noise"
        if name not in protocols:
            print(f"streamfix eval: unknown protocol {name!r}; available: {', '.join(sorted(protocols))}",
                  file=sys.stderr)
            return 2
        if Path(f).is_dir() and not _accepts(protocols[name], "subset"):
            print(f"streamfix eval: {_directory_message(f, name, protocols)}", file=sys.stderr)
            return 2
        plan[name].append(f)
    if args.levels is not None:
        levelless = [name for name in plan if name in _NO_LEVELS]
        if levelless:
            print(f"streamfix eval: --levels does not apply to protocol {', '.join(levelless)} (it has no "
                  "corruption levels)", file=sys.stderr)
            return 2
        for name in plan:
            what, valid = _LEVEL_RANGES.get(name, (None, None))
            bad = [lv for lv in args.levels if valid is not None and not valid(lv)]
            if bad:
                print(f"streamfix eval: --levels {', '.join(f'{lv:g}' for lv in bad)} out of range for protocol "
                      f"{name}: a level there is {what}", file=sys.stderr)
                return 2
    by_protocol: dict[str, list[dict]] = {}
    progress = ProgressLine("eval", forced=args.progress).__enter__()
    try:
        for step, (name, files) in enumerate(plan.items()):
            what = files[0] if len(files) == 1 else f"{len(files)} files" if files else "the default recordings"
            progress.update(f"protocol {name} on {what}", step, len(plan))
            fn = protocols[name]
            kwargs: dict = {"seed": args.seed}  # unset options keep each protocol's own defaults
            if args.rate is not None:
                kwargs["rate_hz"] = args.rate
            if args.levels is not None:
                kwargs["levels"] = args.levels
            if _accepts(fn, "methods"):
                kwargs["methods"] = methods
            for option in ("subset", "limit"):  # protocol-specific options, given only when set
                if getattr(args, option) is not None:
                    if not _accepts(fn, option):
                        print(f"streamfix eval: --{option} does not apply to protocol {name!r}", file=sys.stderr)
                        return 2
                    kwargs[option] = getattr(args, option)
            by_protocol[name] = fn(files, **kwargs)
    except (OSError, ValueError) as exc:
        progress.close()
        print(f"streamfix eval: {exc}", file=sys.stderr)
        return 1
    finally:
        progress.close()
    records = [r for recs in by_protocol.values() for r in recs]
    if args.report:  # plotted reports (streamfix/report), one per input file
        try:
            from ..report import write_file_reports

            for path in write_file_reports(args.files, args.report, args.rate):
                print(f"streamfix eval: wrote {path}", file=sys.stderr)
        except (ModuleNotFoundError, OSError, ValueError) as exc:
            print(f"streamfix eval: --report {args.report}: {exc}", file=sys.stderr)
            return 1
    if args.json:
        json.dump(_clean(records), sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        for name in by_protocol:  # a protocol may bring its own table (run.print_table)
            getattr(protocols[name], "print_table", print_table)(by_protocol[name])
    return 0
