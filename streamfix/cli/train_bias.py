"""``streamfix train-bias``: learn a sensor's pose-dependent bias from paired recordings (sensor + optical mocap)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "learn a sensor's pose-dependent joint bias from paired sensor + optical recordings; write the model and its card"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default=None,
                        help="the paired directory (uiprmd/, keraal/; default: ../shared/data/paired)")
    parser.add_argument("--out", required=True, metavar="PATH",
                        help="model file to write (.npz); its card goes beside it (.md). The shipped one: "
                             "streamfix/sensor_bias/models/kinect_v1_uiprmd.npz")
    parser.add_argument("--workers", type=int, default=2, help="processes running the engine over the takes (default 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pose clustering (default 0)")
    parser.add_argument("--no-eval", action="store_true", help="skip the leave-one-subject-out scores in the card")
    parser.add_argument("--progress", action="store_true", help="draw the progress line even when stderr is not a terminal")


def run(args: argparse.Namespace) -> int:
    from ..sensor_bias.card import write_card
    from ..sensor_bias.train import engine_outputs, fit_layout_model, leave_one_subject_out, paired_takes
    from ..io.pose_bias_model import save_pose_bias
    from .progress import ProgressLine

    out = Path(args.out)
    if out.suffix != ".npz":
        print(f"train-bias: --out {out}: expected a .npz path", file=sys.stderr)
        return 2
    try:
        refs = paired_takes(args.data)
        if not refs:
            raise ValueError("no trustworthy UI-PRMD repetitions found")
        with ProgressLine("train-bias", forced=args.progress) as line:
            takes = engine_outputs(refs, workers=max(1, args.workers),
                                   progress=lambda i, n: line.update("engine output of the takes", i, n))
            line.update("fitting")
            model = fit_layout_model(takes, seed=args.seed)
            if not args.no_eval:
                line.update("leave-one-subject-out scores")
            scores = None if args.no_eval else leave_one_subject_out(takes, seed=args.seed)
        out.parent.mkdir(parents=True, exist_ok=True)
        save_pose_bias(model, out)
        card = write_card(out, model, takes, scores, data_dir=args.data)
    except (OSError, ValueError) as exc:
        print(f"train-bias: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out} and {card}")
    return 0
