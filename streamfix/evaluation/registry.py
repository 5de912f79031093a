"""Methods under comparison, file loading for protocols, and protocol discovery.

A *method* maps a corrupted take to a cleaned one::

    method(positions (T,J,3) m NaN=missing, confidence (T,J), bones (B,2), rate_hz,
           skeleton=None) -> (T,J,3)

``streamfix`` is **what users get** from a recording: what ``streamfix clean`` writes
(:func:`streamfix.cleaning.clean_recording`: the gap filler for a marker set without bones,
then the streaming engine's ``clean`` output on the file schedule,
:meth:`~streamfix.streaming.engine.EngineConfig.for_files`). ``streamfix_serve`` is the same engine
and window solver on ``serve``'s schedule (:class:`~streamfix.streaming.engine.EngineConfig`
defaults: the ``clean`` topic a live consumer receives 0.5 s late). Both are reported:
the file schedule takes each frame from windows that hold it near their middle, which the
live topic's latency bound rules out (:func:`engine_config` says which schedule a method
ran, for measures such as the seam). ``streamfix_whole`` is the default
window pipeline (:func:`streamfix.core.pipeline.clean_window`) run once on the whole
take, which no user command runs; it is kept to measure what windowing costs.
``yang``/``li``/``wang`` are Algorithm 1 and its predecessors via
:func:`streamfix.core.alm.solve` (solver defaults). Baselines users pick: ``one_euro``
(Casiez et al.'s common defaults, min_cutoff 1 Hz, beta 0.5), ``one_euro_tuned``
(min_cutoff 0.5 Hz, beta 2: less jitter at rest, still quick on fast limbs; see
``ONE_EURO_TUNED``), ``holt`` (Kinect SDK defaults; inferred joints get the SDK's doubled
radii), ``savgol``, ``median_savgol``, ``butterworth`` (zero-phase, 2nd order, 6 Hz: the
FreeMoCap / Pose2Sim default), ``linear``, ``spline`` (gap interpolation only; observed
samples pass unchanged). All methods get the same information: the corrupted positions
and the sensor confidence, never the ground truth (bone lengths are estimated from the
input). ``skeleton`` (the layout, for joint names such as left/right) is optional: a
method that needs one builds a nameless layout from ``bones`` when it is not given.
"""
from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path
from typing import Callable

import numpy as np

from ..motion import Motion
from ..skeletons import Skeleton

__all__ = [
    "METHODS",
    "ALL_METHODS",
    "run_method",
    "load_motion",
    "discover_protocols",
    "PROTOCOL_MODULES",
    "is_kinect_file",
    "layout_for",
    "engine_config",
    "handover_frames",
    "ONE_EURO_TUNED",
]

Method = Callable[..., np.ndarray]

ONE_EURO_TUNED = {"min_cutoff": 0.5, "beta": 2.0, "d_cutoff": 1.0}
"""One Euro setting for skeletons at 30 Hz: a lower rest cut-off than the paper's example
(less jitter on still joints) and a larger speed coefficient (less lag on swings)."""


def _input(x, conf, bones, rate, skeleton=None):
    return x.copy()


def layout_for(bones: np.ndarray, n_joints: int, skeleton: Skeleton | None = None) -> Skeleton:
    """``skeleton`` when given, else a nameless layout ``eval_<J>`` with the given bones."""
    if skeleton is not None:
        if len(skeleton.joint_names) != n_joints:
            raise ValueError(f"skeleton {skeleton.name!r} has {len(skeleton.joint_names)} joints, positions have {n_joints}")
        return skeleton
    names = tuple(f"joint{j}" for j in range(n_joints))
    return Skeleton(f"eval_{n_joints}", names, tuple((int(a), int(b)) for a, b in np.asarray(bones).reshape(-1, 2)))


ENGINE_SCHEDULES = {"streamfix": "file", "streamfix_serve": "serve", "streamfix_live": "serve"}
"""The engine methods and the schedule each runs (:func:`streamfix.streaming.config.schedule_config`):
``streamfix`` is what ``streamfix clean`` writes, ``streamfix_serve`` serve's ``clean`` topic and
``streamfix_live`` serve's causal ``live`` topic (judge it beside the causal filters, One Euro and Holt)."""

CLEAN_METHODS = ("streamfix", "streamfix_serve")
"""The engine methods whose output is the cleaned result (what ``clean`` writes and serve's
``clean`` topic publishes): the ones the benchmarks' bars judge."""


def engine_config(method: str, rate_hz: float):
    """The :class:`~streamfix.streaming.engine.EngineConfig` a method ran its windows on
    (:data:`ENGINE_SCHEDULES`); methods without windows get ``serve``'s, so their seams are
    measured where ``serve``'s would be."""
    from ..streaming.config import schedule_config

    return schedule_config(ENGINE_SCHEDULES.get(method, "serve"), rate_hz)


def handover_frames(n_frames: int, rate_hz: float, method: str = "streamfix_serve") -> np.ndarray:
    """``(T,)`` bool: the two frames around each window hand-over of the schedule ``method``
    ran (:func:`engine_config`), where the blend passes a frame to the newer window
    (:func:`streamfix.streaming.blending.handover_frames`): the frames a seam would show on."""
    return engine_config(method, rate_hz).handover_frames(n_frames)


def _engine_method(name: str) -> Method:
    topic = "live" if name == "streamfix_live" else "clean"

    def run(x, conf, bones, rate, skeleton=None, sensor_bias="auto"):
        skel = layout_for(bones, x.shape[1], skeleton)
        times = np.arange(x.shape[0], dtype=np.float64) / float(rate)
        motion = Motion(np.asarray(x, dtype=np.float64), np.asarray(conf, dtype=np.float64), times, float(rate), skel)
        cfg = dataclasses.replace(engine_config(name, rate), sensor_bias=sensor_bias)
        if ENGINE_SCHEDULES[name] == "file":  # exactly what `streamfix clean` writes (the gap filler for markers)
            from ..cleaning import clean_recording

            return clean_recording(motion, cfg).motion.positions
        from ..streaming.offline import clean_motion

        out, _ = clean_motion(motion, cfg, topic=topic)
        return out.positions

    run.__name__ = name
    run.__doc__ = f"The engine's {topic} output on the {ENGINE_SCHEDULES[name]} schedule."
    return run


def _streamfix_whole(x, conf, bones, rate, skeleton=None):
    from ..core.pipeline import clean_window

    return clean_window(x, conf, bones, None, rate).positions


def _solver(mode: str) -> Method:
    def run(x, conf, bones, rate, skeleton=None):
        from ..core.alm import SolverParams, solve

        return solve(x, conf > 0, bones, None, SolverParams(mode=mode)).positions

    run.__name__ = mode
    return run


def _one_euro(x, conf, bones, rate, skeleton=None):
    from ..core.filters import one_euro

    return one_euro(x, rate, conf > 0)


def _one_euro_tuned(x, conf, bones, rate, skeleton=None):
    from ..core.filters import one_euro

    return one_euro(x, rate, conf > 0, **ONE_EURO_TUNED)


def _butterworth(x, conf, bones, rate, skeleton=None):
    from ..core.filters import butterworth

    return butterworth(x, rate, conf > 0)


def _holt(x, conf, bones, rate, skeleton=None):
    from ..core.filters import holt

    return holt(x, conf > 0, (conf > 0) & (conf < 1))


def _savgol(x, conf, bones, rate, skeleton=None):
    from ..core.filters import savgol

    return savgol(x, rate, conf > 0)


def _median_savgol(x, conf, bones, rate, skeleton=None):
    from ..core.filters import median_savgol

    return median_savgol(x, rate, conf > 0)


def _interp(kind: str) -> Method:
    def run(x, conf, bones, rate, skeleton=None):
        from ..core.interpolate import interpolate

        return interpolate(x, conf > 0, kind)[0]

    run.__name__ = kind
    return run


METHODS: dict[str, Method] = {
    "input": _input,
    **{name: _engine_method(name) for name in ENGINE_SCHEDULES},
    "streamfix_whole": _streamfix_whole,
    "yang": _solver("yang"),
    "li": _solver("li"),
    "wang": _solver("wang"),
    "one_euro": _one_euro,
    "holt": _holt,
    "savgol": _savgol,
    "median_savgol": _median_savgol,
    "one_euro_tuned": _one_euro_tuned,
    "butterworth": _butterworth,
    "linear": _interp("linear"),
    "spline": _interp("spline"),
}


def _protocol_methods(modules: tuple[str, ...] = ("occlusion", "long_gaps")) -> tuple[str, ...]:
    """Method names that protocol modules run themselves (``METHODS`` of each module
    present: the occlusion protocol's ``prior_latent`` etc., the long-gap protocol's ``pca`` etc.)."""
    return tuple(str(n) for module in _present_modules(modules) for n in getattr(module, "METHODS", ()))


def _present_modules(names: tuple[str, ...]):
    """Yield the ``streamfix.evaluation.<name>`` modules that exist (absent ones skipped)."""
    for name in names:
        try:
            yield importlib.import_module(f"streamfix.evaluation.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"streamfix.evaluation.{name}":
                raise



def run_method(
    name: str,
    positions: np.ndarray,
    confidence: np.ndarray,
    bones: np.ndarray,
    rate_hz: float,
    skeleton: Skeleton | None = None,
    sensor_bias=None,
) -> np.ndarray:
    """Run method ``name`` (one of :data:`ALL_METHODS`) on a corrupted take.

    ``sensor_bias`` (engine methods only): the pose-bias model setting
    (:mod:`streamfix.sensor_bias.shipped`; None = the engine's default, ``"auto"``); a
    leave-one-subject-out benchmark passes each subject's fold model here.
    """
    try:
        fn = METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; expected one of: {', '.join(ALL_METHODS)}") from None
    x = np.asarray(positions, dtype=np.float64)
    conf = np.where(np.isfinite(x).all(axis=2), np.asarray(confidence, dtype=np.float64), 0.0)
    extra = {} if sensor_bias is None else {"sensor_bias": sensor_bias}
    if extra and name not in ENGINE_SCHEDULES:
        raise ValueError(f"method {name!r} has no sensor-bias setting (only {', '.join(ENGINE_SCHEDULES)})")
    out = fn(np.where(conf[..., None] > 0, x, np.nan), conf, bones, float(rate_hz), skeleton=skeleton, **extra)
    return np.asarray(out, dtype=np.float64)


def is_kinect_file(path: str | Path) -> bool:
    return Path(path).suffix.lower() == ".csv"


def _read(path: Path) -> Motion:
    try:
        from ..io import read_motion  # the I/O layer's dispatcher, when present
    except ImportError:
        read_motion = None
    if read_motion is not None:
        return read_motion(path)
    ext = path.suffix.lower()
    if ext == ".bvh":
        from ..io.bvh import read_bvh

        return read_bvh(path)
    if ext == ".csv":
        from ..io.kinect_csv import read_kinect_csv

        return read_kinect_csv(path)
    raise ValueError(f"{path}: cannot read {ext!r} files (expected .bvh or .csv)")


def load_motion(path: str | Path, rate_hz: float | None = None) -> Motion:
    """Read a motion file and bring it to ``rate_hz`` (None = native rate).

    Resampling is :func:`streamfix.core.resample.resample_positions` (an integer ratio
    such as 120 -> 30 Hz takes every k-th frame exactly); confidence is sampled at the
    nearer source frame and zeroed where the resampled sample is unobserved.
    """
    from ..core.resample import resample_plan, resample_positions

    path = Path(path)
    motion = _read(path)
    if rate_hz is None or abs(rate_hz - motion.rate_hz) < 1e-6 * motion.rate_hz:
        return motion
    pos, obs = resample_positions(motion.positions, motion.rate_hz, rate_hz, motion.observed)
    a, b, w = resample_plan(motion.n_frames, motion.rate_hz, rate_hz)
    near = np.where(w > 0.5, b, a)
    conf = np.where(obs, np.minimum(motion.confidence[a], motion.confidence[b]), 0.0)
    conf = np.where(w[:, None] == 0, np.where(obs, motion.confidence[near], 0.0), conf)
    timestamps = motion.timestamps[0] + np.arange(pos.shape[0]) / float(rate_hz)
    return Motion(pos, conf, timestamps, rate_hz, motion.skeleton, meta=dict(motion.meta))


# Modules under streamfix.evaluation that may define PROTOCOLS = {name: run}.
PROTOCOL_MODULES = ("noise_gaps", "kinect", "occlusion", "long_gaps", "sensor", "paired")


def discover_protocols() -> dict[str, Callable]:
    """``{protocol name: run}`` from every protocol module present (absent ones skipped)."""
    found: dict[str, Callable] = {}
    for module in _present_modules(PROTOCOL_MODULES):
        found.update(getattr(module, "PROTOCOLS", {}))
    return found


# every name ``streamfix eval --methods`` accepts: the window methods above, then the
# protocol-specific ones (a protocol scores the subset it knows). Last in the module:
# the protocol modules import ``load_motion`` from here.
ALL_METHODS = tuple(dict.fromkeys(tuple(METHODS) + _protocol_methods()))
