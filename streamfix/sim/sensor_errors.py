"""What a consumer depth sensor gets wrong, applied to ground-truth Kinect v2 joints.

Pure functions: ground-truth positions ``(T, 25, 3)`` metres in the ``KINECT_V2`` layout
and **camera frame** (z = depth, the subject ~2.5 m in front of the sensor, as
``bvh_to_kinect_v2(to_camera=True)`` puts it), sampled at ``rate_hz`` (30 Hz nominal),
and a seeded ``numpy.random.Generator`` in; corrupted positions, sensor confidence
(1 tracked, 0.5 inferred, 0 missing with NaN positions) and one ``(T, J)`` boolean mask
per error kind out. Each mask marks exactly the joint-frames that kind changed, so a
cleaner can be scored where the sensor was wrong and, separately, where it was right.

Error kinds (:data:`KINDS`):

``noise``
    AR(1) noise on every sample, per camera axis: ``n_t = rho n_{t-1} + sqrt(1 - rho^2)
    sigma e_t`` (stationary from the first frame), larger along depth.
``swap``
    Left/right limb swap for a few frames: an arm (shoulder, elbow, wrist, hand, hand tip,
    thumb) or a leg (hip, knee, ankle, foot) exchanges positions and confidence with its
    mirror joints.
``freeze``
    A limb's distal part (from the elbow or wrist, knee or ankle) stops moving for
    ``freeze_s`` seconds while flagged inferred (0.5): it keeps the pose it had the frame
    before relative to the joint it hangs from (frozen; the sensor's guess still follows
    the tracked body, as a Kinect's inferred limbs do) or that pose moves off at
    ``drift_speed_m_s`` in a fixed random direction (drifting);
    ``freeze_missing_fraction`` of these stretches are flagged missing instead.
``dropout``
    The same limb stretches, always flagged missing (NaN, confidence 0).
``flagged``
    The same limb stretches flagged inferred while the positions stay right: not an
    error but the hazard of trusting the flag (a Kinect infers occluded joints that are
    often near the truth). A cleaner that replaces contradicted inferred limbs must leave
    these where they are; the mask marks the flagged joint-frames (positions unchanged).
    Not in the mix: how often a sensor's inferred limbs are right is not measured.
``spike``
    Single-frame outliers: one joint, one frame, ``3 cm + Exp`` metres in a random direction.
``stretch``
    Bone stretch: a long limb bone's distal joints pushed out along the bone by up to
    ``stretch_fraction`` of its length, with a half-sine envelope over ``stretch_frames``.
``jump``
    Sudden jump: a joint, or a limb's distal part, offset by a step of ``15 cm + Exp``
    metres in a random direction that persists for ``jump_frames`` and then returns.
``depth``
    A limb joint (elbow, wrist, hand, knee, ankle, foot) read at the depth of a wall
    ``depth_behind_m`` behind it for ``depth_frames``, along its own camera ray (its image
    position kept): what a sensor that reads depth per pixel gives a thin limb on the body's
    silhouette (a DepthAI spatial keypoint is the median depth within 10 px of the 2-D
    keypoint). Not in the mix, and its parameters are assumed, not estimated: the Kinect
    recordings here have none (its skeleton tracker reads depth off the body it segments), and
    no per-pixel-depth pose recordings are in the shared data.

``mix`` (:func:`apply_sensor_errors` with ``kinds=MIX_KINDS``) applies all of them at the
rates estimated from real recordings. The estimates, their units and how they were
obtained are in ``docs/SENSOR_ERRORS.md``; their numbers live in ``sensor_errors.json``
beside this module (written by ``tools/estimate_sensor_errors.py``), the single source
of the defaults of :class:`SensorErrorParams`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Iterable

import numpy as np
from scipy import signal

from ..motion import CONFIDENCE_INFERRED, CONFIDENCE_TRACKED
from ..skeletons import KINECT_V2

__all__ = [
    "KINDS",
    "MIX_KINDS",
    "PARENT",
    "SensorErrorParams",
    "Corruption",
    "apply_sensor_errors",
    "ESTIMATES_PATH",
    "MIRROR",
    "SWAP_LIMBS",
    "DISTAL_SEGMENTS",
    "ASSUMED_PARAMETERS",
]

KINDS = ("noise", "swap", "freeze", "dropout", "spike", "stretch", "jump", "flagged", "depth")
# the realistic mix: limb failures come as ``freeze`` with ``freeze_missing_fraction`` of
# them flagged missing (``dropout`` alone is the all-missing variant, for scoring gap filling)
MIX_KINDS = ("noise", "swap", "freeze", "spike", "stretch", "jump")
ESTIMATES_PATH = Path(__file__).with_name("sensor_errors.json")
SPIKE_MIN_M = 0.03  # a spike is at least 3 cm (streamfix.sim.measure's threshold)
JUMP_MIN_M = 0.15  # a jump is a gross failure: at least 15 cm
_J = KINECT_V2.n_joints
_K = KINECT_V2.index
_N_LIMBS = 4


def _mirror_of(name: str) -> str:
    if "Left" in name:
        return name.replace("Left", "Right")
    return name.replace("Right", "Left")


# index j of the mirrored body is joint MIRROR[j] (left <-> right; the spine maps to itself)
MIRROR = np.array([_K(_mirror_of(n)) for n in KINECT_V2.joint_names], dtype=np.intp)
PARENT = np.full(_J, -1, dtype=np.intp)  # KINECT_V2 parent of each joint (-1: the root)
for _p, _c in KINECT_V2.bones:
    PARENT[_c] = _p
_ARM = ("Shoulder", "Elbow", "Wrist", "Hand", "HandTip", "Thumb")
_LEG = ("Hip", "Knee", "Ankle", "Foot")
# the left joints of each swappable limb (their mirrors are MIRROR[...])
SWAP_LIMBS = {"arm": np.array([_K(f"{j}Left") for j in _ARM]), "leg": np.array([_K(f"{j}Left") for j in _LEG])}
# a limb's distal part, from a joint down: what freezes, drifts, stretches or jumps together
DISTAL_SEGMENTS = tuple(
    np.array([_K(f"{j}{side}") for j in chain])
    for side in ("Left", "Right")
    for chain in (("Elbow", "Wrist", "Hand", "HandTip", "Thumb"), ("Wrist", "Hand", "HandTip", "Thumb"),
                  ("Knee", "Ankle", "Foot"), ("Ankle", "Foot"))
)


def _estimates() -> dict:
    try:
        return json.loads(ESTIMATES_PATH.read_text())["parameters"]
    except (OSError, KeyError, ValueError) as exc:
        raise RuntimeError(f"cannot read the sensor error estimates {ESTIMATES_PATH}: {exc}") from exc


_EST = _estimates()


def _default(name: str):
    value = _EST[name]
    return field(default=tuple(value) if isinstance(value, list) else float(value))


ASSUMED_PARAMETERS = ("depth_rate_hz", "depth_frames", "depth_behind_m")
"""Fields of :class:`SensorErrorParams` that are assumed, not estimated (not in ``sensor_errors.json``)."""


@dataclass(frozen=True)
class SensorErrorParams:
    """Rates, sizes and durations of each error kind (defaults: estimated, docs/SENSOR_ERRORS.md).

    Rates are events per second per unit (a left/right pair, a limb, a joint) except
    ``spike_rate`` (per joint-frame); ranges ``(lo, hi)`` are uniform draws.
    ``noise_sigma_m`` (x, y, z) m, camera axes, z = depth; ``noise_rho`` AR(1) per frame.
    ``swap_rate_arm_hz`` / ``swap_rate_leg_hz`` 1/s per pair; ``swap_frames`` frames.
    ``freeze_rate_hz`` 1/s per limb; ``freeze_s`` s; ``freeze_still_fraction``: share frozen
    (the rest drift at ``drift_speed_m_s`` m/s); ``freeze_missing_fraction``: share flagged
    missing. ``spike_rate`` per joint-frame, ``spike_size_m`` median m. ``stretch_rate_hz``
    1/s per limb, ``stretch_frames`` frames, ``stretch_fraction`` peak lengthening.
    ``jump_rate_hz`` 1/s per joint, ``jump_size_m`` median m, ``jump_frames`` frames.
    ``depth_rate_hz`` 1/s per limb joint, ``depth_frames`` frames, ``depth_behind_m`` m
    (assumed, not in ``sensor_errors.json``).
    """

    noise_sigma_m: tuple[float, float, float] = _default("noise_sigma_m")
    noise_rho: float = _default("noise_rho")
    swap_rate_arm_hz: float = _default("swap_rate_arm_hz")
    swap_rate_leg_hz: float = _default("swap_rate_leg_hz")
    swap_frames: tuple[float, float] = _default("swap_frames")
    freeze_rate_hz: float = _default("freeze_rate_hz")
    freeze_s: tuple[float, float] = _default("freeze_s")
    freeze_still_fraction: float = _default("freeze_still_fraction")
    drift_speed_m_s: float = _default("drift_speed_m_s")
    freeze_missing_fraction: float = _default("freeze_missing_fraction")
    spike_rate: float = _default("spike_rate")
    spike_size_m: float = _default("spike_size_m")
    stretch_rate_hz: float = _default("stretch_rate_hz")
    stretch_frames: tuple[float, float] = _default("stretch_frames")
    stretch_fraction: tuple[float, float] = _default("stretch_fraction")
    jump_rate_hz: float = _default("jump_rate_hz")
    jump_size_m: float = _default("jump_size_m")
    jump_frames: tuple[float, float] = _default("jump_frames")
    # assumed (ASSUMED_PARAMETERS, the module doc's ``depth``): one event every ~4 s among the 12 limb joints
    depth_rate_hz: float = 0.02
    depth_frames: tuple[float, float] = (3.0, 60.0)
    depth_behind_m: tuple[float, float] = (0.5, 2.5)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = np.asarray(getattr(self, f.name), dtype=np.float64)
            if not np.all(np.isfinite(v)) or np.any(v < 0):
                raise ValueError(f"SensorErrorParams.{f.name} must be finite and >= 0, got {getattr(self, f.name)}")
        if not -1.0 < self.noise_rho < 1.0:
            raise ValueError(f"noise_rho must be in (-1, 1), got {self.noise_rho}")
        for name in ("freeze_still_fraction", "freeze_missing_fraction"):
            if getattr(self, name) > 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        for name in ("swap_frames", "freeze_s", "stretch_frames", "stretch_fraction", "jump_frames", "depth_frames",
                     "depth_behind_m"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Corruption:
    """Corrupted ``positions`` (T, J, 3) m (NaN = missing), ``confidence`` (T, J) and one
    ``(T, J)`` bool mask per applied kind (True = that kind changed the joint-frame)."""

    positions: np.ndarray
    confidence: np.ndarray
    masks: dict[str, np.ndarray]

    @property
    def gross(self) -> np.ndarray:
        """(T, J) joint-frames changed by any kind but ``noise`` (which touches every sample)."""
        out = np.zeros(self.confidence.shape, dtype=bool)
        for kind, m in self.masks.items():
            if kind != "noise":
                out |= m
        return out

    @property
    def corrupted(self) -> np.ndarray:
        """(T, J) the joint-frames this corruption is about: ``gross`` if any kind but
        ``noise`` was applied, else every joint-frame noise touched."""
        if set(self.masks) == {"noise"}:
            return self.masks["noise"].copy()
        return self.gross


# ---------------------------------------------------------------------------- helpers
def _count(rng: np.random.Generator, expected: float, min_events: int) -> int:
    return max(int(min_events), int(rng.poisson(max(expected, 0.0))))


def _span(rng: np.random.Generator, lo_hi: tuple[float, float], n_frames: int) -> tuple[int, int]:
    """(start, stop) of an event of uniform length in ``lo_hi`` frames, inside [1, T)."""
    length = int(round(rng.uniform(*lo_hi)))
    length = int(np.clip(length, 1, max(n_frames - 1, 1)))
    start = int(rng.integers(1, max(n_frames - length, 1) + 1))
    return start, min(start + length, n_frames)


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    d = rng.standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _excess_size(rng: np.random.Generator, minimum: float, median: float, n: int) -> np.ndarray:
    """``minimum + Exp(mean)`` metres with the given median (mean = (median - min) / ln 2)."""
    mean = max(median - minimum, 1e-3) / np.log(2.0)
    return minimum + rng.exponential(mean, n)


# -------------------------------------------------------------------------- the kinds
def _noise(X, conf, rng, p: SensorErrorParams, rate_hz, min_events):
    T = X.shape[0]
    e = rng.standard_normal(X.shape)
    rho = p.noise_rho
    # stationary AR(1): n_0 = e_0, n_t = rho n_{t-1} + sqrt(1 - rho^2) e_t
    n = np.empty_like(e)
    n[0] = e[0]
    if T > 1:
        n[1:] = signal.lfilter([np.sqrt(1.0 - rho**2)], [1.0, -rho], e[1:], axis=0, zi=(rho * e[0])[None])[0]
    X += n * np.asarray(p.noise_sigma_m)
    return np.isfinite(X).all(axis=2)


def _swap(X, conf, rng, p, rate_hz, min_events):
    T = X.shape[0]
    mask = np.zeros(conf.shape, dtype=bool)
    seconds = T / rate_hz
    rates = np.array([p.swap_rate_arm_hz, p.swap_rate_leg_hz])
    total = rates.sum()
    for _ in range(_count(rng, total * seconds, min_events)):
        limb = "arm" if rng.random() < (rates[0] / total if total > 0 else 0.5) else "leg"
        left = SWAP_LIMBS[limb]
        both = np.concatenate([left, MIRROR[left]])
        s, e = _span(rng, p.swap_frames, T)
        X[s:e, both] = X[s:e, MIRROR[both]]
        conf[s:e, both] = conf[s:e, MIRROR[both]]
        mask[s:e, both] = True
    return mask


def _limb_failure(X, conf, rng, p, rate_hz, min_events, *, always_missing: bool, moves: bool = True):
    T = X.shape[0]
    mask = np.zeros(conf.shape, dtype=bool)
    seconds = T / rate_hz
    lo_hi = (p.freeze_s[0] * rate_hz, p.freeze_s[1] * rate_hz)
    for _ in range(_count(rng, p.freeze_rate_hz * _N_LIMBS * seconds, min_events)):
        seg = DISTAL_SEGMENTS[int(rng.integers(len(DISTAL_SEGMENTS)))]
        s, e = _span(rng, lo_hi, T)
        missing = always_missing or (rng.random() < p.freeze_missing_fraction and moves)
        if missing:
            X[s:e, seg] = np.nan
            conf[s:e, seg] = 0.0
        else:
            anchor = PARENT[seg[0]]  # the joint the failing part hangs from (still tracked)
            pose = X[s - 1, seg] - X[s - 1, anchor]  # (n, 3): the limb's pose before it failed
            steps = np.arange(1, e - s + 1, dtype=np.float64)[:, None, None]
            still = rng.random() < p.freeze_still_fraction
            v = np.zeros(3) if still else p.drift_speed_m_s * _unit_vectors(rng, 1)[0]
            if moves:
                X[s:e, seg] = X[s:e, anchor][:, None] + pose[None] + steps * (v / rate_hz)
            conf[s:e, seg] = np.where(conf[s:e, seg] > 0, CONFIDENCE_INFERRED, 0.0)
        mask[s:e, seg] = True
    return mask


def _freeze(X, conf, rng, p, rate_hz, min_events):
    return _limb_failure(X, conf, rng, p, rate_hz, min_events, always_missing=False)


def _dropout(X, conf, rng, p, rate_hz, min_events):
    return _limb_failure(X, conf, rng, p, rate_hz, min_events, always_missing=True)


def _flagged(X, conf, rng, p, rate_hz, min_events):
    """The freeze stretches flagged inferred, the positions left right (same draws as ``freeze``)."""
    return _limb_failure(X, conf, rng, p, rate_hz, min_events, always_missing=False, moves=False)


def _spike(X, conf, rng, p, rate_hz, min_events):
    T, J = conf.shape
    mask = rng.random((T, J)) < p.spike_rate
    if mask.sum() < min_events:
        extra = rng.choice(T * J, size=int(min_events), replace=False)
        mask.flat[extra] = True
    n = int(mask.sum())
    X[mask] += _unit_vectors(rng, n) * _excess_size(rng, SPIKE_MIN_M, p.spike_size_m, n)[:, None]
    return mask


def _stretch(X, conf, rng, p, rate_hz, min_events):
    T = X.shape[0]
    mask = np.zeros(conf.shape, dtype=bool)
    for _ in range(_count(rng, p.stretch_rate_hz * _N_LIMBS * T / rate_hz, min_events)):
        seg = DISTAL_SEGMENTS[int(rng.integers(len(DISTAL_SEGMENTS)))]
        parent = PARENT[seg[0]]  # the bone parent -> seg[0] is an upper arm, forearm, thigh or shin
        s, e = _span(rng, p.stretch_frames, T)
        envelope = np.sin(np.pi * (np.arange(e - s) + 0.5) / (e - s))[:, None]  # > 0 inside
        bone = X[s:e, seg[0]] - X[s:e, parent]  # (n, 3)
        X[s:e, seg] += (rng.uniform(*p.stretch_fraction) * envelope * bone)[:, None, :]
        mask[s:e, seg] = True
    return mask


def _jump(X, conf, rng, p, rate_hz, min_events):
    T, J = conf.shape
    mask = np.zeros(conf.shape, dtype=bool)
    for _ in range(_count(rng, p.jump_rate_hz * J * T / rate_hz, min_events)):
        if rng.random() < 0.5:
            seg = np.array([int(rng.integers(J))])
        else:
            seg = DISTAL_SEGMENTS[int(rng.integers(len(DISTAL_SEGMENTS)))]
        s, e = _span(rng, p.jump_frames, T)
        step = _unit_vectors(rng, 1)[0] * _excess_size(rng, JUMP_MIN_M, p.jump_size_m, 1)[0]
        X[s:e, seg] += step
        mask[s:e, seg] = True
    return mask


DEPTH_JOINTS = np.array([_K(f"{j}{side}") for side in ("Left", "Right")
                         for j in ("Elbow", "Wrist", "Hand", "Knee", "Ankle", "Foot")])
DEPTH_MIN_M = 1.0  # a joint nearer the sensor than this has no wall behind it in a room


def _depth(X, conf, rng, p, rate_hz, min_events):
    T = X.shape[0]
    mask = np.zeros(conf.shape, dtype=bool)
    for _ in range(_count(rng, p.depth_rate_hz * len(DEPTH_JOINTS) * T / rate_hz, min_events)):
        j = int(DEPTH_JOINTS[int(rng.integers(len(DEPTH_JOINTS)))])
        for _try in range(20):  # a span where the joint stands in the room, in front of the sensor
            s, e = _span(rng, p.depth_frames, T)
            if (X[s:e, j, 2] > DEPTH_MIN_M).all():
                break
        else:
            continue
        z = X[s:e, j, 2]
        wall = z.max() + rng.uniform(*p.depth_behind_m)
        X[s:e, j] *= (wall / z)[:, None]  # the same ray from the sensor, the wall's depth
        mask[s:e, j] = True
    return mask


# order of application in a mix: noise on every sample first, limb failures last (a
# frozen limb holds a value the sensor reported, a missing one has none)
_APPLY = {"noise": _noise, "swap": _swap, "stretch": _stretch, "jump": _jump, "spike": _spike,
          "depth": _depth, "freeze": _freeze, "dropout": _dropout, "flagged": _flagged}


def apply_sensor_errors(
    truth: np.ndarray,
    rng: np.random.Generator,
    kinds: Iterable[str] = MIX_KINDS,
    params: SensorErrorParams | None = None,
    rate_hz: float = 30.0,
    min_events: int = 0,
) -> Corruption:
    """Corrupt ground truth ``(T, 25, 3)`` m (camera frame, KINECT_V2 order) with ``kinds``.

    Event counts are Poisson with the estimated rates (``params``) over the take's length
    ``T / rate_hz`` s, but at least ``min_events`` per kind (a protocol scoring one kind
    needs it to happen). Kinds apply in a fixed order (noise, swap, stretch, jump, spike,
    depth, freeze, dropout) whatever the order given; a later kind may overwrite an earlier one's
    joint-frames (both masks then mark them). Returns a :class:`Corruption`.
    """
    X = np.array(truth, dtype=np.float64)
    if X.ndim != 3 or X.shape[1:] != (_J, 3):
        raise ValueError(f"truth must be (T, {_J}, 3) metres in the KINECT_V2 layout, got {X.shape}")
    if X.shape[0] < 3:
        raise ValueError(f"truth needs at least 3 frames, got {X.shape[0]}")
    if not np.isfinite(X).all():
        raise ValueError(f"truth must be complete ground truth, {int((~np.isfinite(X).all(axis=2)).sum())} joint-frames are missing")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number of Hz, got {rate_hz}")
    wanted = list(dict.fromkeys(kinds))
    unknown = [k for k in wanted if k not in KINDS]
    if unknown or not wanted:
        raise ValueError(f"unknown error kind(s) {unknown or wanted}; expected some of: {', '.join(KINDS)}")
    p = params if params is not None else SensorErrorParams()
    conf = np.full(X.shape[:2], CONFIDENCE_TRACKED)
    masks = {}
    for kind, fn in _APPLY.items():
        if kind in wanted:
            masks[kind] = fn(X, conf, rng, p, float(rate_hz), int(min_events))
    return Corruption(X, conf, {k: masks[k] for k in wanted})
