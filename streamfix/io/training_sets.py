"""Reference takes for PCA gap filling (:mod:`streamfix.core.pca_gapfill`).

A training set is a list of complete-ish recordings of the *same* joint or marker
set as the motion to fill. :func:`load_training_set` reads files or every motion
file of a directory, matches their joints/markers to the target's by name (a
``Subject:`` prefix, as CMU C3D files carry, is ignored; case-insensitive) and
returns a :class:`~streamfix.core.pca_gapfill.TrainingSet` in the target's order.
Files whose names do not cover the target's are skipped and reported in
``skipped``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ..core.pca_gapfill import TrainingSet
from ..motion import Motion

__all__ = ["load_training_set", "match_joints", "MOTION_SUFFIXES"]

MOTION_SUFFIXES = (".c3d", ".bvh", ".csv", ".sfrec")


def _key(name: str) -> str:
    return str(name).split(":")[-1].strip().lower()


def match_joints(source_names: Sequence[str], target_names: Sequence[str]) -> np.ndarray | None:
    """Indices into ``source_names`` giving ``target_names``' order, or None if any is absent."""
    index = {}
    for i, n in enumerate(source_names):
        index.setdefault(_key(n), i)
    try:
        return np.array([index[_key(n)] for n in target_names], dtype=np.intp)
    except KeyError:
        return None


def _expand(paths: str | Path | Iterable[str | Path]) -> list[Path]:
    if isinstance(paths, (str, Path)):
        paths = [paths]
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out += sorted(q for q in p.iterdir() if q.suffix.lower() in MOTION_SUFFIXES)
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"{p}: training take not found (expected a motion file or a directory)")
    return out


def load_training_set(
    paths: str | Path | Iterable[str | Path],
    target: Motion | Sequence[str],
    *,
    layout: str = "sequence",
    exclude: Iterable[str | Path] = (),
    skipped: list | None = None,
) -> TrainingSet | None:
    """Reference takes matching ``target``'s joints (a Motion or a list of joint names).

    ``exclude``: files never to train on (e.g. the take being filled). Rate
    differences are ignored (PCA over poses does not depend on the rate; Eq. (16)'s
    temporal basis does, so give takes of the target's rate for blackouts). Returns
    None when no file matches; ``skipped`` (a list) collects ``(path, reason)``.
    """
    from . import read_motion

    names = list(target.skeleton.joint_names) if isinstance(target, Motion) else list(target)
    excl = {Path(p).resolve() for p in exclude}
    motions = []
    for path in _expand(paths):
        if path.resolve() in excl:
            continue
        try:
            m = read_motion(path)
        except Exception as exc:  # a bad reference take is skipped, not fatal
            if skipped is not None:
                skipped.append((str(path), str(exc)))
            continue
        idx = match_joints(m.skeleton.joint_names, names)
        if idx is None:
            if skipped is not None:
                skipped.append((str(path), f"joint/marker names do not cover the target's {len(names)}"))
            continue
        x = m.positions[:, idx].copy()
        x[~m.observed[:, idx]] = np.nan
        motions.append(x)
    if not motions:
        return None
    return TrainingSet(motions, layout=layout)
