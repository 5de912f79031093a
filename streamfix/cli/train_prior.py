"""``streamfix train-prior``: train the autoencoder prior (Lohit et al.) and export it to ONNX."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .options import add_list_argument

# streamfix.prior.train.TrainConfig's defaults (that module imports torch; --help must not need it)
_DEFAULTS = {"epochs": 600, "steps_per_epoch": 60, "latent": 32, "channels": 96, "proportion_sigma": 0.08}

HELP = "train the learned motion prior (temporal-conv autoencoder, canonical body) on the shared recordings; export ONNX + card"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default="../shared/data",
                        help="directory holding cmu_bvh/, xia_bvh/, kinect_v2/, c3d/ and paired/uiprmd/ (default: ../shared/data)")
    parser.add_argument("--out", help="output directory for canonical.{encoder,decoder,decoder_jacobian}.onnx and canonical.json")
    parser.add_argument("--rescore", metavar="CARD",
                        help="train nothing: score the held-out takes of an exported model's card (a canonical.json) "
                             "again with this version's inference and rewrite the card and its .md")
    parser.add_argument("--int8-jacobian", metavar="CARD",
                        help="train nothing: run an exported card's decoder-Jacobian tangent products in 8-bit "
                             "integers, as export does (about half the latent fit's cost; cards exported by older "
                             "versions have them in float32), then rescore it as --rescore does")
    parser.add_argument("--epochs", type=int, default=_DEFAULTS["epochs"], help="epochs of --steps batches")
    parser.add_argument("--steps", type=int, default=_DEFAULTS["steps_per_epoch"], help="batches per epoch")
    parser.add_argument("--seed", type=int, default=0, help="seed for weights, windows, augmentation and masks (default 0)")
    parser.add_argument("--latent", type=int, default=_DEFAULTS["latent"], help="latent size L")
    parser.add_argument("--channels", type=int, default=_DEFAULTS["channels"], help="feature maps per conv layer")
    parser.add_argument("--proportion-sigma", type=float, default=_DEFAULTS["proportion_sigma"],
                        help="augmentation: scale each bone by exp(N(0, sigma)), left and right alike "
                             f"(default {_DEFAULTS['proportion_sigma']}; 0: off)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--device", default="cpu",
                        help="torch device to train on, e.g. cpu or cuda (same batches; weights differ by float rounding)")
    parser.add_argument("--workers", type=int, default=0,
                        help="processes drawing training batches beside the training loop (same batches for any number)")
    parser.add_argument("--share", action="append", default=[], metavar="SOURCE=W",
                        help="a source's share of each batch, e.g. bvh=0.2 (repeatable; the rest keep "
                             "streamfix.prior.data.SOURCE_SHARES; shares are renormalised)")
    add_list_argument(parser, "--held-out", metavar="NAME",
                      help="take names or groups to hold out, as 'a b' or 'a,b' "
                           "(default: 131_02 neutral_01_000 Ges04_comehere uiprmd_s06)")
    parser.add_argument("--no-eval", action="store_true", help="skip the held-out occlusion scores in the card")
    parser.add_argument("--no-kinect-v1", action="store_true",
                        help="leave out UI-PRMD's Kinect v1 skeletons (partially observed data)")

def run(args: argparse.Namespace) -> int:
    try:
        import torch  # noqa: F401
    except ModuleNotFoundError:
        print("streamfix train-prior needs PyTorch: pip install streamfix[train]", file=sys.stderr)
        return 2
    import warnings

    warnings.filterwarnings("ignore", message=".*padding='same'.*")
    from streamfix.prior.data import HELD_OUT, SOURCE_SHARES
    from streamfix.prior.train import TrainConfig, train_and_export

    data = Path(args.data)
    if not data.is_dir():
        print(f"train-prior: data directory {data} not found", file=sys.stderr)
        return 2
    if args.rescore and args.int8_jacobian:
        print("train-prior: give --rescore CARD or --int8-jacobian CARD (which rescores too), not both", file=sys.stderr)
        return 2
    if args.rescore or args.int8_jacobian:
        from streamfix.prior.train import quantize_card_jacobian, rescore_card

        option, card = ("--int8-jacobian", args.int8_jacobian) if args.int8_jacobian else ("--rescore", args.rescore)
        try:
            if args.int8_jacobian:
                quantize_card_jacobian(card)
            rescore_card(card, data, log=lambda s: print(s, flush=True))
        except (OSError, ValueError, KeyError) as exc:
            print(f"train-prior {option} {card}: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 2
        return 0
    if not args.out:
        print("train-prior: --out DIR is required (or --rescore CARD)", file=sys.stderr)
        return 2
    held = tuple(args.held_out) if args.held_out else HELD_OUT
    shares = dict(SOURCE_SHARES)
    for item in args.share:
        source, _, weight = item.partition("=")
        try:
            if source not in SOURCE_SHARES:
                raise ValueError(f"unknown source {source!r} (sources: {', '.join(SOURCE_SHARES)})")
            shares[source] = float(weight)
            if not shares[source] >= 0:
                raise ValueError("a share is a number >= 0")
        except ValueError as exc:
            print(f"train-prior: --share {item}: {exc}", file=sys.stderr)
            return 2
    if args.workers < 0:
        print(f"train-prior: --workers {args.workers}: must be >= 0", file=sys.stderr)
        return 2
    cfg = TrainConfig(epochs=args.epochs, seed=args.seed, channels=args.channels, latent=args.latent,
                      steps_per_epoch=args.steps, threads=args.threads, proportion_sigma=args.proportion_sigma,
                      shares=shares, device=args.device, workers=args.workers)
    train_and_export(data, args.out, cfg, held_out=held, log=lambda s: print(s, flush=True), evaluate=not args.no_eval,
                     kinect_v1=not args.no_kinect_v1)
    return 0
