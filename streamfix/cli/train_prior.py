"""``streamfix train-prior``: train the autoencoder prior (Lohit et al.) and export it to ONNX."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "train the learned motion prior (temporal-conv autoencoder) on BVH + Kinect v2 data and export ONNX + card"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", default="../shared/data",
                        help="directory holding cmu_bvh/, xia_bvh/ (BVH) and kinect_v2/ (CSV) (default: ../shared/data)")
    parser.add_argument("--out", required=True, help="output directory for kinect_v2.{encoder,decoder,decoder_jacobian}.onnx and kinect_v2.json")
    parser.add_argument("--epochs", type=int, default=60, help="epochs of --steps batches (default 60)")
    parser.add_argument("--steps", type=int, default=40, help="batches per epoch (default 40)")
    parser.add_argument("--seed", type=int, default=0, help="seed for weights, windows, augmentation and masks (default 0)")
    parser.add_argument("--latent", type=int, default=32, help="latent size L (default 32)")
    parser.add_argument("--channels", type=int, default=64, help="feature maps per conv layer (default 64)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--held-out", default=None,
                        help="comma-separated take names to hold out (default: 131_02,neutral_01_000,Ges04_comehere)")
    parser.add_argument("--no-eval", action="store_true", help="skip the held-out occlusion scores in the card")
    parser.add_argument("--with-markers", action="store_true",
                        help="also train on the CMU full-body marker C3D takes under c3d/ (joints approximated from "
                             "markers; off by default: it made the held-out D(z*) worse)")


def run(args: argparse.Namespace) -> int:
    try:
        import torch  # noqa: F401
    except ModuleNotFoundError:
        print("streamfix train-prior needs PyTorch: pip install streamfix[train]", file=sys.stderr)
        return 2
    import warnings

    warnings.filterwarnings("ignore", message=".*padding='same'.*")
    from streamfix.prior.data import HELD_OUT
    from streamfix.prior.train import TrainConfig, train_and_export

    data = Path(args.data)
    if not data.is_dir():
        print(f"train-prior: data directory {data} not found", file=sys.stderr)
        return 2
    held = tuple(s for s in args.held_out.split(",") if s) if args.held_out else HELD_OUT
    cfg = TrainConfig(epochs=args.epochs, seed=args.seed, channels=args.channels, latent=args.latent,
                      steps_per_epoch=args.steps, threads=args.threads)
    train_and_export(data, args.out, cfg, held_out=held, log=lambda s: print(s, flush=True), evaluate=not args.no_eval,
                     include_markers=args.with_markers)
    return 0
