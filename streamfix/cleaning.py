"""What ``streamfix clean`` does to one recording, as a function: Motion in, cleaned Motion out.

One code path for every offline caller: the ``clean`` command, the archive runner
(:mod:`streamfix.archive`) and ``streamfix.clean(..., mode="offline")`` all call
:func:`clean_recording`, so a file cleaned from Python, from the command line or on a
cluster is the same array.

The steps: marker files without bones first go through the gap filler
(:func:`streamfix.gapfill.fill_motion_gaps`, PCA trained on the take's own observed
samples plus optional reference takes): offline the filler sees both ends of every gap,
and the engine's learned prior and bone projection know nothing of a marker set. Joint
files go to the engine as they are: its bridge fills their long gaps from the body's clean
history, the learned prior and time (:mod:`streamfix.streaming.bridging`). The filler ran on
joint files with long gaps too until it was measured there: on the sensor protocol's limbs
lost for 0.5-3 s it left far more error than the engine, there and on the other joints,
and on the paper's gap protocol it mostly lost.
Then the streaming engine runs in synchronous mode
(:func:`streamfix.streaming.offline.clean_motion`) on the file schedule
(:meth:`~streamfix.streaming.engine.EngineConfig.for_files`): the same window solver as
``serve``, with each frame taken from windows that hold it near their middle (a file has
no latency bound) and half as many windows solved. Given ``serve``'s schedule
(``EngineConfig(rate_hz=...)``) the result equals ``serve``'s ``clean`` output on the
gap-filled frames. Filled samples stay flagged recovered.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np

from .core.points import finite_points
from .core.units import units_problem
from .motion import Motion
from .streaming.engine import EngineConfig

__all__ = ["CleanedRecording", "clean_recording"]


@dataclass
class CleanedRecording:
    """The result of :func:`clean_recording`.

    motion: the cleaned motion (``recovered`` set). source: the input as given.
    metrics: the engine's counters. notes: human-readable remarks (gap filler used).
    gapfilled: ``(T, J)`` bool of input samples the gap filler made, or None when it did not run.
    """

    motion: Motion
    source: Motion
    metrics: dict
    notes: list[str] = field(default_factory=list)
    gapfilled: np.ndarray | None = None


def clean_recording(
    motion: Motion,
    config: EngineConfig | None = None,
    *,
    gapfill: bool = True,
    training: Iterable | str | None = None,
    keep_filled: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> CleanedRecording:
    """Clean one recording the way ``streamfix clean`` does (the gap filler for a marker set
    without bones, then the engine).

    ``config`` None = :meth:`EngineConfig.for_files` at the motion's rate. ``gapfill`` False skips
    the gap filler; ``training``: reference takes for it (files / directories; a note says
    they went unused on a skeleton with bones). Raises ValueError when the positions cannot
    be metres (:func:`streamfix.core.units.units_problem`: millimetres by mistake), and
    ``ValueError`` / ``OSError`` from the gap filler with a message saying so, and
    :class:`~streamfix.streaming.offline.WindowSolverError` when no window solved; windows
    that failed among solved ones are counted in ``metrics['solver_errors']``.
    """
    from .streaming.offline import clean_motion

    wrong_units = units_problem(motion.positions, motion.skeleton.bone_array)
    if wrong_units:
        raise ValueError(f"{motion.meta.get('source', 'the recording')}: positions must be in metres: {wrong_units}")
    cfg = config if config is not None else EngineConfig.for_files(motion.rate_hz)
    source = motion
    notes: list[str] = []
    gapfilled = None
    if training and motion.skeleton.n_bones:
        notes.append("reference takes unused: the gap filler runs on marker sets without bones; "
                     "the engine bridges a skeleton's gaps itself")
    if motion.skeleton.n_bones == 0 and gapfill and not motion.observed.all():
        from .gapfill import fill_motion_gaps

        try:
            filled = fill_motion_gaps(motion, training=training)
        except (OSError, ValueError) as exc:
            raise (OSError if isinstance(exc, OSError) else ValueError)(f"gap filling: {exc}") from exc
        gapfilled = filled.recovered & ~motion.observed if filled.recovered is not None else None
        motion = filled
        info = filled.meta.get("gapfill", {})
        note = f"gaps filled by streamfix.gapfill ({info.get('training_takes')} training takes"
        if info.get("plausibility") is not None:
            note += f", rigid-pair plausibility {info['plausibility']:.2f}"
        notes.append(note + ")")
    cleaned, metrics = clean_motion(motion, cfg, keep_filled=keep_filled, progress=progress)
    if gapfilled is not None and cleaned.recovered is not None and gapfilled.any():
        # the engine saw the filled samples as data: keep them flagged as recovered
        times = np.asarray(source.timestamps)
        idx = np.clip(np.searchsorted(times, np.asarray(cleaned.timestamps)), 0, source.n_frames - 1)
        same = np.isclose(times[idx], cleaned.timestamps, atol=0.25 / source.rate_hz)
        rec = cleaned.recovered.copy()
        rec[same] |= gapfilled[idx[same]]
        cleaned.recovered = rec
        cleaned.confidence = np.where(rec & finite_points(cleaned.positions),
                                      np.minimum(cleaned.confidence, 0.5), cleaned.confidence)
    return CleanedRecording(cleaned, source, metrics, notes, gapfilled)
