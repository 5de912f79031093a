"""Fill long gaps and blackouts in a whole :class:`~streamfix.motion.Motion` (offline).

The hook ``streamfix clean`` calls for marker files (C3D) and for joint files whose
gaps are longer than the solver window::

    from streamfix.gapfill import fill_motion_gaps
    motion = fill_motion_gaps(motion)                       # trains on the take itself
    motion = fill_motion_gaps(motion, training="refs/")     # + reference takes (files/dir)

Partial gaps are filled by Li et al. (2020) Eq. (4) (local templates), whole missing
frames by Eq. (16) blended with a spline (for marker sets, each marker's spline in the frame
of its most rigid neighbours, :mod:`streamfix.core.corotating`), leftovers by linear interpolation (see
:mod:`streamfix.core.pca_gapfill`). The take's own observed samples always train the
model (never a gap: missing samples are NaN), so nothing needs to be prepared. For
marker sets (a skeleton without bones) the filled markers are then projected so that
the take's most rigid marker pairs keep the distance range observed where both are
visible. Filled samples get confidence 0.5 (a recovered estimate) and
``motion.recovered`` True; observed samples are never changed.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from .core import pca_gapfill as pg
from .core.pca_fill import pca_fill
from .core.excursion import anchor_reference, limit_excursion, parents_from_bones
from .motion import CONFIDENCE_INFERRED, Motion

__all__ = ["fill_motion_gaps", "RIGID_PAIRS"]

TRUST_KAPPA = 5.0
"""Skeleton takes: a gap's PCA fill keeps its departure from linear interpolation only
where that departure is large against ``TRUST_KAPPA`` x the model's error at the gap's
ends. Measured on Kinect v2 takes with one limb blanked: still limbs (a seated 3 s leg, a
still arm) come out near linear, moving arms keep PCA's far smaller error than linear's,
and a gap whose ends the model missed falls back to about linear's error; a larger kappa
helps the seated leg and costs the moving arm."""

RIGID_PAIRS = 60
"""Number of rigid marker pairs kept in range for marker sets (0 = no projection)."""


def _training(motion: Motion, training) -> pg.TrainingSet:
    own = motion.positions.copy()
    own[~motion.observed] = np.nan
    if training is None:
        return pg.TrainingSet([own])
    if isinstance(training, (str, Path)) or (
        isinstance(training, (list, tuple)) and training and isinstance(training[0], (str, Path))
    ):
        from .io.training_sets import load_training_set

        exclude = [motion.meta["source"]] if "source" in motion.meta else []
        ts = load_training_set(training, motion, exclude=exclude)
        refs = [] if ts is None else list(ts.motions)
    elif isinstance(training, pg.TrainingSet):
        refs = list(training.motions)
    elif isinstance(training, np.ndarray):
        refs = [training]
    else:
        refs = list(training)
    for k, r in enumerate(refs):
        if np.shape(r)[1:] != (motion.n_joints, 3):
            raise ValueError(f"training take {k}: expected (T, {motion.n_joints}, 3), got {np.shape(r)}")
    return pg.TrainingSet(refs + [own])


def fill_motion_gaps(
    motion: Motion,
    training: pg.TrainingSet | np.ndarray | Iterable | str | Path | None = None,
    *,
    energy: float = pg.DEFAULT_ENERGY,
    n_partners: int | tuple[int, ...] | None = pg.DEFAULT_PARTNERS,
    rigid_pairs: int | None = None,
    blackout_window: int | None = None,
    excursion_gain: float | None = None,
    trust_kappa: float | None = -1.0,
) -> Motion:
    """A copy of ``motion`` with its missing samples filled and flagged as recovered.

    ``training``: None (the take's own observed samples), reference takes as arrays
    ``(T_k, J, 3)`` m / a :class:`~streamfix.core.pca_gapfill.TrainingSet`, or file /
    directory paths (matched by joint/marker name). ``rigid_pairs``: how many rigid
    marker pairs to keep in their observed distance range (default
    :data:`RIGID_PAIRS` for bone-less marker sets, 0 for skeletons).
    ``blackout_window``: frames per Eq. (16) window (default 200 frames at 120 Hz,
    scaled with the rate). ``excursion_gain``: filled joints stay within this many times
    their own range of motion over the 1 s next to the gap of the linear interpolation
    (:func:`~streamfix.core.excursion.limit_excursion`; None = off, the default:
    measured on Kinect arm/leg gaps it helps a seated 3 s leg gap (still worse than linear)
    but makes a 45-frame gap of an arm moving inside the gap far worse,
    because offline both ends are seen and the limb's motion *inside* the gap is not
    in its range next to the gap). ``trust_kappa``: each gap's PCA fill is shrunk toward
    linear interpolation unless its departure from linear is large against the model's
    error at the gap's ends (:func:`~streamfix.core.pca_boundary.shrink_untrusted`;
    default :data:`TRUST_KAPPA` for skeletons with bones, off for marker sets; None =
    off). A summary goes to ``meta["gapfill"]``.
    """
    out = motion.copy()
    obs = motion.observed
    if obs.all() or not obs.any():
        out.meta["gapfill"] = {"filled": 0}
        return out
    ts = _training(motion, training)
    window = blackout_window or max(int(round(200 * motion.rate_hz / 120.0)), 20)
    kappa = (TRUST_KAPPA if motion.skeleton.n_bones else None) if trust_kappa == -1.0 else trust_kappa
    marker_set = motion.skeleton.n_bones == 0
    filled_pos, filled = pca_fill(motion.positions, obs, ts, energy=energy, n_partners=n_partners,
                                  blackout_window=window, trust_kappa=kappa, corotating=marker_set)
    n_pairs = rigid_pairs if rigid_pairs is not None else (RIGID_PAIRS if marker_set else 0)
    summary: dict = {"filled": int(filled.sum()), "training_takes": len(ts.motions)}
    if n_pairs and filled.any():
        pairs = pg.estimate_rigid_pairs(motion.positions, obs, k=n_pairs)
        if len(pairs):
            lo, hi = pg.pair_distance_ranges(motion.positions, obs, pairs)
            summary["plausibility_before"] = pg.pair_distance_plausibility(filled_pos, obs, filled, pairs)
            filled_pos = pg.project_pair_distances(filled_pos, filled, pairs, lo, hi)
            summary["plausibility"] = pg.pair_distance_plausibility(filled_pos, obs, filled, pairs)
            summary["rigid_pairs"] = int(len(pairs))
    gain = excursion_gain
    if gain is not None and filled.any():
        # a whole limb missing: PCA guesses its pose from coincidental correlations with
        # the rest of the body (a seated 3 s leg gap: far worse than linear); keep it near
        # linear unless the limb itself was moving
        ref = None
        if motion.skeleton.n_bones:
            ref = anchor_reference(filled_pos, obs, parents_from_bones(motion.skeleton.bone_array, motion.n_joints))
        filled_pos = limit_excursion(filled_pos, obs, filled, max(1, int(round(motion.rate_hz))), gain=gain,
                                     reference=ref)
        summary["excursion_gain"] = gain
    filled_pos[obs] = motion.positions[obs]
    out.positions = filled_pos
    out.confidence = np.where(filled, CONFIDENCE_INFERRED, motion.confidence)
    rec = filled if motion.recovered is None else (motion.recovered | filled)
    out.recovered = rec
    out.meta["gapfill"] = summary
    return out
