"""The Python API: clean an array of joint positions in one call.

``streamfix.clean(positions, rate_hz, skeleton)`` takes a ``(T, J, 3)`` array in metres
(NaN = missing joint) and returns the cleaned positions and a ``(T, J)`` mask of the
samples that were recovered rather than observed. The ``mode`` picks which of the
project's outputs you get; each is the same code the command line and the service run:

``"offline"``
    what ``streamfix clean`` writes (:func:`streamfix.cleaning.clean_recording`: the gap
    filler on long gaps, then the streaming engine on the file schedule:
    long windows, :meth:`~streamfix.streaming.config.EngineConfig.for_files`).
``"stream"``
    what ``streamfix serve`` publishes on its ``clean`` topic (the streaming engine,
    synchronous, with serve's default window, hop and 0.5 s lookahead; a threaded
    ``serve`` equals it while it is not degrading under load, ``serve --sync`` always).
``"live"``
    what ``streamfix serve`` publishes on its ``live`` topic (the causal per-frame path:
    no lookahead, rougher).

Frames are taken as uniformly sampled at ``rate_hz`` (Hz). The skeleton is a registered
name (``"kinect_v2"``, ``"coco17"``, ...; :func:`streamfix.skeletons.skeleton_names`) or
a :class:`~streamfix.skeletons.Skeleton`, e.g. built with
:meth:`Skeleton.from_parents <streamfix.skeletons.Skeleton.from_parents>`.

>>> import numpy as np, streamfix
>>> t = np.arange(90) / 30.0                                  # 3 s at 30 Hz
>>> arm = streamfix.Skeleton.from_parents("doc_arm", ["shoulder", "elbow", "wrist"], [None, 0, 1])
>>> angle = 0.5 * np.sin(2 * np.pi * 0.5 * t)
>>> elbow = np.stack([0.3 * np.cos(angle), 0.3 * np.sin(angle), 0 * t], axis=1)
>>> positions = np.stack([0 * elbow, elbow, elbow + [0.25, 0.0, 0.0]], axis=1)  # (90, 3, 3) metres
>>> positions[40:46, 2] = np.nan                              # the wrist lost for 6 frames
>>> cleaned, recovered = streamfix.clean(positions, 30.0, arm)
>>> cleaned.shape, recovered.shape, bool(np.isfinite(cleaned).all())
((90, 3, 3), (90, 3), True)
>>> bool(recovered[40:46, 2].all()), int(recovered.sum())
(True, 6)
>>> streamfix.clean(positions[:, :2], 30.0, arm)
Traceback (most recent call last):
...
ValueError: positions have 2 joints per frame; skeleton 'doc_arm' expects 3 (shoulder, elbow, wrist)
"""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np

from .core.units import units_problem
from .motion import Motion
from .skeletons import Skeleton, get_skeleton

__all__ = ["clean", "MODES"]

MODES = {
    "offline": "what `streamfix clean` writes: the gap filler on marker sets without bones, then the streaming engine (file schedule)",
    "stream": "what `streamfix serve` publishes on `clean`",
    "live": "what `streamfix serve` publishes on `live` (causal, no lookahead)",
}


def _skeleton(skeleton: str | Skeleton) -> Skeleton:
    if isinstance(skeleton, Skeleton):
        return skeleton
    if isinstance(skeleton, str):
        try:
            return get_skeleton(skeleton)
        except KeyError as exc:
            raise ValueError(exc.args[0]) from None
    raise TypeError(
        f"skeleton must be a registered name or a streamfix.Skeleton, got {type(skeleton).__name__} "
        "(build one with streamfix.Skeleton.from_parents(name, joint_names, parents))"
    )


def _motion(positions, rate_hz: float, skeleton: Skeleton, confidence, timestamps=None) -> Motion:
    """Check shapes and units up front; errors name what was expected and what arrived."""
    try:
        pos = np.array(positions, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("positions must be a numeric (T, J, 3) array in metres") from None
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3) metres, got shape {pos.shape}")
    if pos.shape[1] != skeleton.n_joints:
        names = ", ".join(skeleton.joint_names)
        raise ValueError(
            f"positions have {pos.shape[1]} joints per frame; skeleton {skeleton.name!r} expects "
            f"{skeleton.n_joints} ({names if len(names) < 120 else names[:117] + '...'})"
        )
    if pos.shape[0] < 1:
        raise ValueError("positions hold no frames")
    try:
        rate = float(rate_hz)
    except (TypeError, ValueError):
        raise ValueError(f"rate_hz must be a positive number (Hz), got {rate_hz!r}") from None
    if not (np.isfinite(rate) and rate > 0):
        raise ValueError(f"rate_hz must be a positive number (Hz), got {rate_hz!r}")
    conf = None
    if confidence is not None:
        conf = np.array(confidence, dtype=np.float64)
        if conf.shape != pos.shape[:2]:
            raise ValueError(f"confidence must be (T, J) = {pos.shape[:2]}, got shape {conf.shape}")
        if not np.isfinite(conf).all() or conf.min() < 0 or conf.max() > 1:
            raise ValueError("confidence must lie in [0, 1] (1 tracked, 0.5 inferred, 0 missing)")
    wrong_units = units_problem(pos, skeleton.bone_array)
    if wrong_units:
        raise ValueError(f"positions must be in metres: {wrong_units}")
    motion = Motion.from_positions(pos, skeleton, rate, confidence=conf)
    if timestamps is not None:
        try:
            times = np.array(timestamps, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("timestamps must be a numeric (T,) array in seconds") from None
        if times.shape != (pos.shape[0],):
            raise ValueError(f"timestamps must be (T,) = ({pos.shape[0]},) seconds, got shape {times.shape}")
        if not np.isfinite(times).all() or (np.diff(times) <= 0).any():
            raise ValueError("timestamps must be finite seconds, increasing from frame to frame")
        motion.timestamps = times
    return motion


@contextmanager
def _prior(path: str | Path | None) -> Iterator[None]:
    """Use the prior at ``path`` for this call only (None = the current default)."""
    if path is None:
        yield
        return
    from .prior import runtime

    before = getattr(runtime, "_DEFAULT_PATH", None)
    try:
        runtime.set_default_prior(path)  # a bad path raises here, after setting it: restore below
        yield
    finally:
        runtime.set_default_prior(before)


def clean(
    positions: np.ndarray,
    rate_hz: float,
    skeleton: str | Skeleton,
    confidence: np.ndarray | None = None,
    mode: str = "offline",
    prior: str | Path | None = None,
    sensor_bias: str | Path = "auto",
    timestamps: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Clean ``(T, J, 3)`` joint positions (metres, NaN = missing) sampled at ``rate_hz`` (Hz).

    Parameters
    ----------
    positions:
        ``(T, J, 3)`` metres; a NaN coordinate marks the joint missing in that frame.
    rate_hz:
        Nominal frame rate in Hz; frames are taken as uniformly spaced unless ``timestamps`` are given.
    skeleton:
        A registered skeleton name or a :class:`~streamfix.skeletons.Skeleton` with ``J`` joints.
    confidence:
        Optional ``(T, J)`` in [0, 1] (1 tracked, 0.5 inferred, 0 missing); default: 1
        where the position is finite, else 0.
    mode:
        ``"offline"`` (``streamfix clean``), ``"stream"`` (serve's ``clean`` topic) or
        ``"live"`` (serve's ``live`` topic); see :data:`MODES`.
    prior:
        A learned prior (model card ``.json`` or its directory, as written by
        ``streamfix train-prior``) used for this call; None = the current default.
    sensor_bias:
        The learned pose-dependent sensor bias removed from the output (``--sensor-bias``
        of ``clean`` / ``serve``): ``"auto"`` (the model shipped for the skeleton, if any),
        ``"off"``, or a model file written by ``streamfix train-bias``.
    timestamps:
        Optional ``(T,)`` sensor times in seconds (a recording's ``Motion.timestamps``). A
        sensor drops frames; with its times the engine fills them as ``clean`` and ``serve``
        do (the result then equals theirs), without them every frame is one period after
        the last and a drop is a jump.

    Returns
    -------
    (cleaned, recovered):
        ``(T, J, 3)`` float64 metres and ``(T, J)`` bool, True where the value was
        recovered rather than observed.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(repr(m) for m in MODES)}; got {mode!r}")
    motion = _motion(positions, rate_hz, _skeleton(skeleton), confidence, timestamps)
    from .streaming.config import schedule_config

    bias = str(sensor_bias)
    with _prior(prior):
        if mode == "offline":
            from .cleaning import clean_recording

            cleaned = clean_recording(motion, schedule_config("file", motion.rate_hz, sensor_bias=bias)).motion
        else:
            from .streaming.offline import clean_motion

            cleaned, _ = clean_motion(motion, schedule_config("serve", motion.rate_hz, sensor_bias=bias),
                                      topic="clean" if mode == "stream" else "live")
    recovered = cleaned.recovered if cleaned.recovered is not None else np.zeros(cleaned.positions.shape[:2], bool)
    return cleaned.positions, recovered
