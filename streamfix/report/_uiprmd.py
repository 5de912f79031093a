"""``uiprmd_s01-s06.npz:KEY`` names one UI-PRMD paired repetition for a report.

The loading and alignment are :func:`streamfix.io.paired.load_uiprmd_take`'s (one reader
for the paired data); this module only parses the ``FILE.npz:KEY`` form a user types.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.paired import load_uiprmd_take
from ..motion import Motion

__all__ = ["parse_paired_spec", "read_paired"]


def parse_paired_spec(text: str) -> tuple[Path, str] | None:
    """``FILE.npz:KEY`` -> (path, key); None when ``text`` is not of that form."""
    path, sep, key = str(text).rpartition(":")
    if not sep or not path.lower().endswith(".npz") or not key:
        return None
    return Path(path), key


def read_paired(path: str | Path, key: str) -> tuple[Motion, np.ndarray]:
    """The repetition's Kinect motion and its optical reference ``(T, 22, 3)`` (NaN: no reference)."""
    take = load_uiprmd_take(path, key)
    return take.sensor, take.reference
