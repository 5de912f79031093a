"""The per-stream engines ``streamfix serve`` drives (``--engine``).

``streamfix`` (default)
    :class:`streamfix.streaming.engine.StreamEngine`: the causal ``live`` fast path and
    the windowed ``clean`` solver (threaded, never blocking the input).
``passthrough``
    Emits every input frame unchanged on ``live`` and ``clean`` at once. It is the
    baseline of ``benchmarks/bench_service.py`` (socket + encoding cost alone) and a
    way to run the service's plumbing without the solver.

An engine offers ``push(frame, fill=True) -> [(kind, frame)]`` (``fill=False``: frames
before this one were shed, do not synthesise them), ``flush(timeout) -> [(kind, frame)]``,
optionally ``poll() -> [(kind, frame)]`` (outputs finished in the background) and
``metrics() -> dict``; ``kind`` is ``"live"`` or ``"clean"``.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from ..frames import SkeletonFrame
from ..skeletons import Skeleton

__all__ = ["EngineOptions", "PassthroughEngine", "engine_factory", "prepare_streamfix_engine", "parse_lookahead", "ENGINES"]


@dataclass
class EngineOptions:
    """Command-line engine settings; None leaves the engine's default."""

    window: int | None = None       # frames per solved window
    hop: int | None = None          # frames between solves
    lookahead: float | None = None  # seconds of lookahead for the clean output
    lookahead_frames: int | None = None  # or frames (wins if given)
    threaded: bool = True           # solve windows off the input thread
    solver_process: bool = False    # ... in a child process per engine (threaded only; solver_process.py)
    sensor_bias: Any = "auto"       # learned sensor bias removed from clean: auto | off | a model file (or a loaded model)


class PassthroughEngine:
    """``live`` and ``clean`` = the input frame, immediately (no cleaning)."""

    def __init__(self, skeleton: Skeleton, rate_hz: float, options: EngineOptions | None = None) -> None:
        self.skeleton = skeleton
        self.rate_hz = rate_hz
        self._frames = 0

    def push(self, frame: SkeletonFrame, fill: bool = True) -> list[tuple[str, SkeletonFrame]]:
        self._frames += 1
        clean = copy.copy(frame)
        clean.bodies = [copy.copy(b) for b in frame.bodies]
        for b in clean.bodies:
            b.recovered = np.zeros(b.positions.shape[0], dtype=bool)
        return [("live", clean), ("clean", clean)]

    def poll(self) -> list[tuple[str, SkeletonFrame]]:
        return []

    def flush(self, timeout: float | None = None) -> list[tuple[str, SkeletonFrame]]:
        return []

    def metrics(self) -> dict:
        return {"frames_in": self._frames, "degraded": False, "lookahead_frames": 0}

    def close(self) -> None:
        pass


def _streamfix_engine(skeleton: Skeleton, rate_hz: float, options: EngineOptions):
    from ..streaming.engine import StreamEngine  # imported lazily: scipy/pywt cost

    solver = None
    if options.solver_process:
        from ..streaming.solver_process import ProcessWindowSolver

        solver = ProcessWindowSolver()  # takes the child prepare_streamfix_engine started, else forks one
    try:
        # the service polls every engine after handling what arrived: clean work waits for that
        return StreamEngine(skeleton, _engine_config(rate_hz, options), solver, clean_on_poll=True)
    except BaseException:
        if solver is not None:
            solver.close()
        raise


def _engine_config(rate_hz: float, options: EngineOptions):
    from ..streaming import engine as eng

    config_cls = getattr(eng, "EngineConfig", None) or getattr(eng, "StreamConfig")
    kwargs: dict = {}
    fields = getattr(config_cls, "__dataclass_fields__", {})
    if "rate_hz" in fields:
        kwargs["rate_hz"] = float(rate_hz)
    if options.window is not None:
        kwargs["window"] = int(options.window)
    if options.hop is not None:
        kwargs["hop"] = int(options.hop)
    if options.lookahead_frames is not None:
        kwargs["lookahead"] = int(options.lookahead_frames)
    elif options.lookahead is not None:
        kwargs["lookahead_s"] = float(options.lookahead)
    if "threaded" in fields:
        kwargs["threaded"] = bool(options.threaded)
    if options.sensor_bias != "auto":
        kwargs["sensor_bias"] = options.sensor_bias
    if options.solver_process and not options.threaded:
        raise ValueError("a solver process serves the engine's worker thread: it needs threaded mode (not --sync)")
    unknown = [k for k in kwargs if fields and k not in fields]
    if unknown:
        raise ValueError(f"the streaming engine's config has no {', '.join(unknown)} setting")
    return config_cls(**kwargs)


ENGINES: dict[str, Callable] = {
    "streamfix": _streamfix_engine,
    "passthrough": PassthroughEngine,
}


def parse_lookahead(text: str) -> tuple[float | None, int | None]:
    """``--lookahead``: ``0.5`` or ``0.5s`` = seconds, ``15f`` = frames -> (seconds, frames)."""
    t = text.strip().lower()
    try:
        if t.endswith("f"):
            frames = int(t[:-1])
            if frames < 0:
                raise ValueError
            return None, frames
        seconds = float(t[:-1] if t.endswith("s") else t)
        if not seconds >= 0:
            raise ValueError
        return seconds, None
    except ValueError:
        raise ValueError(f"--lookahead {text!r}: expected seconds (0.5 or 0.5s) or frames (15f), >= 0") from None


def engine_factory(name: str, options: EngineOptions) -> Callable[[Skeleton, float], object]:
    """``factory(skeleton, rate_hz) -> engine`` for ``--engine NAME``."""
    try:
        make = ENGINES[name]
    except KeyError:
        raise ValueError(f"unknown engine {name!r}; expected one of {', '.join(ENGINES)}") from None
    if name == "streamfix":
        options = _sensor_bias_loaded(options)
        _engine_config(30.0, options)  # bad --window/--hop/--lookahead fail now, not on the first frame
        prepare_streamfix_engine(solver_process=options.solver_process)
    return lambda skeleton, rate_hz: make(skeleton, rate_hz, options)


def _sensor_bias_loaded(options: EngineOptions) -> EngineOptions:
    """``options`` with its sensor-bias model read now, once: a model file becomes the loaded
    model every stream's engine shares, and with ``auto`` the shipped models are cached.
    Otherwise each new stream's engine read its file on its first frame, on the input loop."""
    from ..sensor_bias.shipped import is_model_path, preload_shipped_models

    if is_model_path(options.sensor_bias):
        from ..io.pose_bias_model import load_pose_bias

        return replace(options, sensor_bias=load_pose_bias(options.sensor_bias))
    if isinstance(options.sensor_bias, str) and options.sensor_bias.lower() == "auto":
        preload_shipped_models()
    return options


def prepare_streamfix_engine(solver_process: bool = False) -> None:
    """Do once, before any frame arrives, what the first stream's engine would otherwise do on
    its first frame: import the engine, compile or load the compiled kernels, load the prior;
    with ``solver_process``, also start the solver processes' forkserver and the first
    engine's child (:func:`~streamfix.streaming.solver_process.prepare_solver_process`),
    which warm up beside this process.

    Doing it on the input path (the kernels' cache load alone outlasts the 50 ms backlog)
    made the service shed the first frames of the first stream.
    """
    from ..core import kernels
    from ..prior.runtime import load_default_prior
    from ..streaming.window_solvers import default_window_solver, import_solver_modules

    child_ready = None
    if solver_process:
        from ..streaming.solver_process import prepare_solver_process

        child_ready = prepare_solver_process()
    default_window_solver()  # imports the engine's solver stack (scipy, pywt: slow imports)
    import_solver_modules()  # and what each engine's constructor imports (the prior's initialiser, PCA)
    kernels.warm_up()
    try:
        load_default_prior()  # the --prior the command chose, else the shipped one; cached per process
    except (FileNotFoundError, ValueError):
        pass  # no usable prior: the bridge falls back without it, as it would on the first window
    if child_ready is not None:
        child_ready()
