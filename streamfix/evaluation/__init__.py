"""Evaluation protocols (the papers' experiments on our data): corrupt ground truth, clean, score.

Each protocol module exposes ``PROTOCOLS = {name: run}`` with
``run(paths, *, rate_hz, levels, seed, methods=None) -> list[dict]``;
:func:`streamfix.evaluation.registry.discover_protocols` collects them for ``streamfix eval``.
Methods under comparison live in :mod:`streamfix.evaluation.registry`.
"""
from .registry import ALL_METHODS, discover_protocols, load_motion, run_method

__all__ = ["ALL_METHODS", "discover_protocols", "load_motion", "run_method"]
