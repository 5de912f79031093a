"""Offline cleaning of a whole :class:`~streamfix.motion.Motion` through the streaming engine.

:func:`clean_motion` feeds the motion's arrays into a synchronous
:class:`~streamfix.streaming.engine.StreamEngine` (one body, id 0; ``push_arrays``, the
frames ``motion_frames`` would make, without making them) and collects its
``clean`` output: with ``serve``'s schedule (the :class:`EngineConfig` defaults) a file
cleaned offline equals what ``streamfix serve`` emits on ``clean`` for the same frames;
``streamfix clean`` passes the file schedule (:meth:`EngineConfig.for_files`). The result
is a pure function of the input. When only
``clean`` is collected the engine runs with ``live_output=False``: the live path's
per-frame work is skipped (its output would be thrown away; ``clean`` is the same).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from ..core.points import finite_points
from ..frames import BodyFrame, SkeletonFrame
from ..motion import Motion
from .engine import EngineConfig, StreamEngine, WindowSolver
from .solver_api import WindowSolverError

__all__ = ["WindowSolverError", "clean_motion", "motion_frames"]


def sensor_times_ns(motion: Motion) -> np.ndarray:
    """``(T,)`` int64: the motion's timestamps (s) as the frames' sensor times (ns)."""
    return np.round(np.asarray(motion.timestamps) * 1e9).astype(np.int64)


def motion_frames(motion: Motion, stream_id: str = "offline", body_id: int = 0, seq0: int = 0):
    """Yield the motion as one-body :class:`SkeletonFrame` objects (sensor time in ns)."""
    name = motion.skeleton.name
    t_ns = sensor_times_ns(motion)
    for i in range(motion.n_frames):
        yield SkeletonFrame(
            stream_id, seq0 + i, int(t_ns[i]), name, [BodyFrame(body_id, motion.positions[i], motion.confidence[i])]
        )


def _run_engine(motion: Motion, cfg: EngineConfig, window_solver, topic: str, progress) -> tuple[list, dict]:
    """Push every frame of ``motion`` through a synchronous engine; the ``topic`` frames and metrics."""
    engine = StreamEngine(motion.skeleton, cfg, window_solver)
    kept: list[SkeletonFrame] = []
    total = motion.n_frames
    step = max(1, total // 100)
    t_ns = sensor_times_ns(motion)  # as motion_frames makes them
    positions, confidence = np.asarray(motion.positions), np.asarray(motion.confidence)
    for start in range(0, total, step):  # a hundredth at a time: the engine takes runs of frames
        end = min(total, start + step)
        got = engine.push_arrays("offline", 0, positions[start:end], confidence[start:end], t_ns[start:end], start)
        kept.extend(out for kind, out in got if kind == topic)
        if progress is not None:
            progress(end, total)
    kept.extend(out for kind, out in engine.flush() if kind == topic)
    return kept, engine.metrics()


def clean_motion(
    motion: Motion,
    config: EngineConfig | None = None,
    window_solver: WindowSolver | None = None,
    *,
    keep_filled: bool = False,
    progress: Callable[[int, int], None] | None = None,
    topic: str = "clean",
) -> tuple[Motion, dict]:
    """Clean ``motion`` with the streaming engine (synchronous mode).

    ``config`` None = :class:`EngineConfig` at the motion's rate. Frames the engine
    synthesises for timestamp gaps are dropped from the result unless ``keep_filled``
    (so by default the output has the input's frames and timestamps).
    ``progress(done, total)`` is called now and then. Returns ``(cleaned motion,
    engine metrics)``; the cleaned motion's ``recovered`` marks recovered joints.
    ``topic="live"`` collects the causal ``live`` output instead of ``clean``.
    Raises :class:`WindowSolverError` when ``clean`` is asked for and every window failed;
    when only some failed, ``metrics['solver_errors']`` counts them (their frames hold
    the live path's values) and ``metrics['first_solver_error']`` says why.
    """
    if topic not in ("clean", "live"):
        raise ValueError(f"topic must be 'clean' or 'live', got {topic!r}")
    cfg = config if config is not None else EngineConfig(rate_hz=motion.rate_hz)
    if cfg.threaded:
        cfg = replace(cfg, threaded=False)
    if topic == "clean" and cfg.live_output:
        cfg = replace(cfg, live_output=False)  # the live topic is discarded: do not compute it
    clean, metrics = _run_engine(motion, cfg, window_solver, topic, progress)
    if topic == "clean" and metrics.get("solver_errors", 0) and not metrics.get("windows_solved", 0):
        raise WindowSolverError(
            f"every window solve failed ({metrics['solver_errors']} windows); the first raised "
            f"{metrics.get('first_solver_error')}")
    if not cfg.live_output and metrics.get("joints_live_fallback", 0):
        # some joint-frames had no window value and would have taken the live path's:
        # run again with it, so the output is exactly the engine's (rare: failed windows)
        cfg = replace(cfg, live_output=True)
        clean, metrics = _run_engine(motion, cfg, window_solver, topic, None)
    frames = [f for f in clean if keep_filled or not f.filled]
    J = motion.n_joints
    pos = np.full((len(frames), J, 3), np.nan)
    conf = np.zeros((len(frames), J))
    rec = np.ones((len(frames), J), dtype=bool)
    times = np.zeros(len(frames))
    for k, f in enumerate(frames):
        times[k] = f.sensor_time_ns * 1e-9
        if f.bodies:
            b = f.bodies[0]
            pos[k] = b.positions
            conf[k] = b.confidence
            rec[k] = b.recovered if b.recovered is not None else False
    # a recovered joint is data now: give it the "inferred" confidence if it had none
    finite = finite_points(pos)
    conf = np.where(finite & (conf <= 0), 0.5, conf)
    if not keep_filled and len(frames) == motion.n_frames:
        times = np.asarray(motion.timestamps, dtype=np.float64).copy()  # bit-exact input times
    out = Motion(pos, conf, times, motion.rate_hz, motion.skeleton, recovered=rec, meta=dict(motion.meta))
    return out, metrics
