"""Solving one scheduled window: the warm start from the body's previous window, the call
into the window solver, and what the job keeps of its answer.

The engine (:mod:`streamfix.streaming.engine`) schedules jobs and blends their results;
this runs in its worker thread in threaded mode. A failing solver never loses frames:
the error is kept on the job and its frames fall back to other windows or the live value.
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..skeletons import Skeleton
from .bodies import Body, Job
from .solver_api import JUDGED_KEY, NOISE_SHARE_KEY, RELEASED_KEY, WindowSolver

__all__ = ["solve_job", "warm_start_state"]


def warm_start_state(body: Body, job: Job, window: int) -> Any:
    """The solver state to start ``job``'s window from (None: cold).

    The previous window's state shifted by the hop when both windows have the full length
    ``window`` (frames); for windows of other lengths (a stream's first windows grow) a
    state with per-frame memory (the frozen-limb release) is ``reframed`` onto the new
    window, without the warm start.
    """
    T = job.end - job.start
    state = None
    prev = body.solver_state
    if prev is not None and T == window:
        shift = job.end - body.solver_state_end
        n_prev = getattr(prev, "n_frames", None)
        if n_prev is None and hasattr(prev, "A"):
            n_prev = prev.A.shape[0]
        if 0 <= shift < T and n_prev == T:
            try:
                state = prev.shifted(shift) if hasattr(prev, "shifted") else prev
            except Exception:  # a state that cannot shift: solve cold
                state = None
    if state is None and prev is not None and hasattr(prev, "reframed"):
        prev_start = body.solver_state_end - prev.n_frames
        state = prev.reframed(job.start - prev_start, T)
    return state


def solve_job(
    job: Job,
    solver: WindowSolver,
    bones: np.ndarray,
    rate_hz: float,
    window: int,
    config: Any = None,
    *,
    pass_history: bool = False,
    skeleton: Skeleton | None = None,
) -> dict[str, int]:
    """Solve ``job``'s window; set its result (or its error) and the body's solver state.

    ``config``: the solver config for this window (None: the solver's default);
    ``pass_history``: hand the solver the body's clean history; ``skeleton``: passed when
    not None. Returns the joint-frames the solver bridged per source (``{}`` if none),
    for the engine's counters.
    """
    body = job.body
    kwargs: dict[str, Any] = {"state": warm_start_state(body, job, window)}
    if pass_history:
        kwargs["history"] = job.history
    if skeleton is not None:
        kwargs["skeleton"] = skeleton
    if config is not None:
        kwargs["config"] = config
    bridged: dict[str, int] = {}
    t0 = time.perf_counter()
    try:
        lengths = job.bone_lengths.resolve()  # here, not when scheduled: off the live path
        res = solver(job.positions, job.confidence, bones, lengths, rate_hz, **kwargs)
        pos = np.asarray(res.positions, dtype=np.float64)
        if pos.shape != job.positions.shape:
            raise ValueError(f"window solver returned {pos.shape}, expected {job.positions.shape}")
        rec = getattr(res, "recovered", None)
        rec = np.zeros(pos.shape[:2], dtype=bool) if rec is None else np.asarray(rec, dtype=bool)
        job.result_pos, job.result_rec = pos, rec
        job.n_iter = int(getattr(res, "iterations", 0) or 0)
        info = getattr(res, "info", None) or {}
        job.noise_share = float(np.clip(info.get(NOISE_SHARE_KEY, 0.0), 0.0, 1.0))
        job.noise_reported = NOISE_SHARE_KEY in info
        judged = info.get(JUDGED_KEY)
        job.judged = None if judged is None or np.shape(judged) != rec.shape else np.asarray(judged, dtype=bool)
        released = info.get(RELEASED_KEY)
        job.released = None if released is None or np.shape(released) != rec.shape else np.asarray(released, dtype=bool)
        job.converged = bool(getattr(res, "converged", True))
        bridged = dict(getattr(res, "bridged", None) or {})
        new_state = getattr(res, "state", None)
        body.solver_state = new_state
        body.solver_state_end = job.end if new_state is not None else -1
    except Exception as exc:  # a failing window must not lose the frames
        job.error = f"{type(exc).__name__}: {exc}"
        body.solver_state = None
        body.solver_state_end = -1
    job.solve_s = time.perf_counter() - t0
    if job.status == "pending":
        job.status = "done"
    return bridged
