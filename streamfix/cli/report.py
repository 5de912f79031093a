"""``streamfix report IN [CLEANED] -o report.html|png``: figures of an offline cleaning.

Examples::

    streamfix report ../shared/data/kinect_v2/seated_joints.csv -o seated.html
    streamfix clean rec.csv rec_clean.csv && streamfix report rec.csv rec_clean.csv -o rec.png
    streamfix report ../shared/data/paired/uiprmd/uiprmd_s01-s06.npz:cor_m07_s02_e01 -o rep.html

IN is any file ``streamfix clean`` reads, or a UI-PRMD paired repetition
``FILE.npz:KEY`` (then the optical reference is overlaid and each joint's error before
and after is charted). Without CLEANED, IN is cleaned with the streaming engine (what
``streamfix clean`` writes). Output: ``.html`` (PNGs embedded) or one ``.png``.
Needs matplotlib (``pip install streamfix[report]``).
"""
from __future__ import annotations

import argparse
import math
import sys

from .options import add_list_argument, positive_number

HELP = "plot an offline cleaning (trajectories, bone lengths, jitter spectrum, recovered joints) to HTML or PNG"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", help="motion file (Kinect CSV, BVH, C3D, .sfrec) or UI-PRMD FILE.npz:KEY")
    p.add_argument("cleaned", metavar="CLEANED", nargs="?", default=None,
                   help="the cleaned file (default: clean IN with the streaming engine)")
    p.add_argument("-o", "--out", required=True, metavar="OUT", help="report.html or report.png")
    add_list_argument(p, "--joints", metavar="NAME",
                      help="joints whose trajectories to plot, as 'a b' or 'a,b' (default: the two that move most)")
    p.add_argument("--reference", default=None, metavar="FILE.npz:KEY",
                   help="overlay this UI-PRMD repetition's optical reference (a FILE.npz:KEY input brings its own)")
    p.add_argument("--rate", type=positive_number("Hz"), default=None, metavar="HZ", help="resample IN to HZ first (default: native)")


def run(args: argparse.Namespace) -> int:
    try:
        from ..report import load_report_data, write_report
    except ModuleNotFoundError as exc:
        print(f"streamfix report: needs {exc.name} (pip install 'streamfix[report]')", file=sys.stderr)
        return 2
    joints = args.joints or None
    if not args.out.lower().endswith((".html", ".htm", ".png")):
        print(f"streamfix report: -o {args.out}: expected a .html or .png file name", file=sys.stderr)
        return 2
    try:
        data = load_report_data(args.input, args.cleaned, reference=args.reference, joints=joints, rate_hz=args.rate)
        summary = write_report(data, args.out)
    except (OSError, ValueError, KeyError) as exc:
        print(f"streamfix report: {exc}", file=sys.stderr)
        return 1
    cv = (f", bone CV {summary['bone_cv_raw_pct']:.2f} -> {summary['bone_cv_clean_pct']:.2f} %"
          if math.isfinite(summary["bone_cv_raw_pct"]) else "")  # a marker set has no bones
    print(f"streamfix report: wrote {args.out} ({data.name}: jitter {summary['jitter_raw_mm']:.3f} -> "
          f"{summary['jitter_clean_mm']:.3f} mm/frame^2{cv})", file=sys.stderr)
    return 0
