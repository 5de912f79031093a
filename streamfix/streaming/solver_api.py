"""What the streaming engine asks of a window solver: its call signature
(:data:`WindowSolver`) and what it returns (:class:`WindowOutput`). Kept apart from the
engine so solvers (:mod:`streamfix.streaming.bridging`) need not import the engine."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

__all__ = ["NOISE_SHARE_KEY", "RELEASED_KEY", "JUDGED_KEY", "WindowOutput", "WindowSolver", "WindowSolverError"]

NOISE_SHARE_KEY = "sensor_noise_share"
"""Key of a window solver's ``info``: in [0, 1], how much of the window is sensor noise
that the engine may smooth at the output (:func:`~streamfix.streaming.overlap_add.smooth_output`); absent
= 0, the output is left as the solver gave it. ``clean_window`` writes its stage-3 gate. The live
topic's One Euro filter follows it too (:meth:`streamfix.streaming.live.LivePath.set_noise_share`;
absent: the filter keeps its configured strength)."""

RELEASED_KEY = "released"
"""Key of a window solver's ``info``: ``(T, J)`` bool, the samples it judged the sensor's
frozen guess or a limb's jump and replaced (:mod:`streamfix.streaming.frozen_release`,
:mod:`streamfix.core.limb_jumps`). An older window that saw less of the run kept them as
measurements; the engine drops what those blended there
(:func:`~streamfix.streaming.overlap_add.blend_window`)."""

JUDGED_KEY = "judged"
"""Key of a window solver's ``info``: ``(T, J)`` bool, the samples its real-sensor stages judged
wrong: replaced (a frozen or jumped limb, a dislocated end, a folded leg, an inferred limb the
body contradicts) or relabelled from their left/right twin (a swap, which stays observed, not
``recovered``). Not a depth thrown along its camera ray, which the live path repairs itself
frame by frame, nor the solver's own outliers, which include a limb that merely moved faster
than the window's edge could follow. The engine's live topic carries the window's verdict on
these (:mod:`streamfix.streaming.live_carry`)."""

WindowSolver = Callable[..., Any]
"""``solver(positions (T,J,3), confidence (T,J), bones (B,2), bone_lengths (B,)|None,
rate_hz, config=..., state=None, init=None)`` returning an object with ``.positions
(T,J,3)``, ``.recovered (T,J)``, ``.state``, ``.iterations``, ``.converged`` -- the
signature of :func:`streamfix.core.pipeline.clean_window`."""


@dataclass
class WindowOutput:
    """What a window solver returns (the fields the engine uses)."""

    positions: np.ndarray
    recovered: np.ndarray
    state: Any = None
    iterations: int = 0
    converged: bool = True
    info: dict = field(default_factory=dict)
    bridged: dict = field(default_factory=dict)  # source -> joint-frames filled before the solver


class WindowSolverError(RuntimeError):
    """The window solver cannot clean: it cannot be imported (an incomplete installation),
    or every window of a recording failed. Without it the engine's ``clean`` output would
    be its live path's, not a cleaning, so commands stop and say why."""
