"""A procedural Kinect v2 body: 25 joints driven by smooth joint-angle trajectories.

The body is built in a body frame (y up, facing +z, the subject's left at +x) from
bone lengths (metres; the medians measured on real Kinect v2 recordings by
:func:`streamfix.sim.measure.measure_kinect`) and rest directions, posed by forward
kinematics (one loop over the joints, vectorised over frames)::

    G_j = G_parent(j) @ R_j(t)                 global orientation
    x_j = x_parent(j) + G_parent(j) @ (L_j d_j)   d_j the rest direction of bone parent->j

and then put into Kinect camera space: turned 180 deg about y (facing the sensor, the
subject's left at -x as the SDK reports it) and shifted so SpineBase sits at the
placement (a measured median SpineBase) plus the activity's own root motion.

Joint angles (degrees) per joint are ``(flex, abd, twist)`` and
``R = Rz(s abd) Rx(-flex) Ry(s twist)`` with ``s = +1`` on the left, ``-1`` on the
right: arm/hip flexion > 0 swings the limb forward, abduction > 0 away from the body,
elbow flexion > 0 folds the forearm forward; knees take negative flexion (they fold
backwards); spine and neck flexion < 0 leans forward. Every trajectory is a sum of
minimum-jerk transitions (``10 s^3 - 15 s^4 + 6 s^5``) and slow sinusoids, so the
clean motion is smooth (no power above ~5 Hz).

Activities: ``standing`` (idle sway, waving, reaching, drawing lines, beckoning, a side
step), ``seated`` (seated at a desk close to the sensor, gesturing, foot tapping),
``stepping`` (stepping in place with arm swing while turning and moving back and forth).
"""
from __future__ import annotations

import numpy as np

from ..io.bvh import axis_rotations
from ..motion import Motion
from ..skeletons import KINECT_V2

__all__ = ["ACTIVITIES", "generate_clean", "pose_body", "rest_directions", "TOPO_ORDER"]

K = KINECT_V2.index
_PARENT = {c: p for p, c in KINECT_V2.bones}
TOPO_ORDER = [0]
while len(TOPO_ORDER) < KINECT_V2.n_joints:
    for c in range(KINECT_V2.n_joints):
        if c not in TOPO_ORDER and _PARENT.get(c) in TOPO_ORDER:
            TOPO_ORDER.append(c)
_BONE_OF_CHILD = {c: i for i, (p, c) in enumerate(KINECT_V2.bones)}


def _u(*v: float) -> np.ndarray:
    a = np.array(v, dtype=np.float64)
    return a / np.linalg.norm(a)


def rest_directions() -> dict[int, np.ndarray]:
    """Unit rest direction of the bone ending at each non-root joint (body frame)."""
    d = {
        "SpineMid": _u(0, 1, 0), "SpineShoulder": _u(0, 1, 0), "Neck": _u(0, 1, 0.05), "Head": _u(0, 1, 0.05),
    }
    for side, s in (("Left", 1.0), ("Right", -1.0)):
        d.update({
            f"Shoulder{side}": _u(s, -0.3, 0), f"Elbow{side}": _u(0, -1, 0), f"Wrist{side}": _u(0, -1, 0),
            f"Hand{side}": _u(0, -1, 0), f"HandTip{side}": _u(0, -1, 0), f"Thumb{side}": _u(-0.3 * s, -1, 1),
            f"Hip{side}": _u(s, -0.35, 0), f"Knee{side}": _u(0, -1, 0), f"Ankle{side}": _u(0, -1, 0),
            f"Foot{side}": _u(0, -0.35, 1),
        })
    return {K(n): v for n, v in d.items()}


def _side(j: int) -> float:
    return -1.0 if "Right" in KINECT_V2.joint_names[j] else 1.0


def pose_body(angles: dict[str, np.ndarray], root_pos: np.ndarray, root_yaw: np.ndarray,
              bone_length: np.ndarray) -> np.ndarray:
    """Forward kinematics: (T, 25, 3) body-frame positions (m).

    ``angles[name]`` is (T, 3) degrees (flex, abd, twist) for any joint (absent = 0);
    ``root_pos`` (T, 3) m, ``root_yaw`` (T,) degrees about y; ``bone_length`` (24,) m.
    """
    T = len(root_yaw)
    J = KINECT_V2.n_joints
    dirs = rest_directions()
    G = np.empty((J, T, 3, 3))
    X = np.empty((J, T, 3))
    zero = np.zeros((T, 3))
    for j in TOPO_ORDER:
        flex, abd, tw = np.asarray(angles.get(KINECT_V2.joint_names[j], zero), dtype=np.float64).T
        s = _side(j)
        R = axis_rotations(2, s * abd) @ axis_rotations(0, -flex) @ axis_rotations(1, s * tw)
        if j == 0:
            G[j] = axis_rotations(1, root_yaw) @ R
            X[j] = root_pos
        else:
            p = _PARENT[j]
            G[j] = G[p] @ R
            X[j] = X[p] + G[p] @ (bone_length[_BONE_OF_CHILD[j]] * dirs[j])
    return X.transpose(1, 0, 2)


# ----------------------------------------------------------------- trajectories
def _mj(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Minimum-jerk ramp from 0 (t <= t0) to 1 (t >= t1)."""
    s = np.clip((t - t0) / max(t1 - t0, 1e-9), 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


def _env(t: np.ndarray, t0: float, t1: float, ramp: float = 1.0) -> np.ndarray:
    """0 -> 1 over [t0, t0+ramp], 1 -> 0 over [t1-ramp, t1]."""
    return _mj(t, t0, t0 + ramp) * (1.0 - _mj(t, t1 - ramp, t1))


def _sway(t: np.ndarray, rng: np.random.Generator, amp: float, fmin: float = 0.08, fmax: float = 0.5, n: int = 3) -> np.ndarray:
    f = rng.uniform(fmin, fmax, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    return amp * np.sin(2 * np.pi * f[None, :] * t[:, None] + ph).sum(axis=1) / np.sqrt(n)


class _Track:
    def __init__(self, t: np.ndarray):
        self.t = t
        self.a: dict[str, np.ndarray] = {}

    def add(self, joint: str, flex=0.0, abd=0.0, twist=0.0) -> None:
        cur = self.a.setdefault(joint, np.zeros((len(self.t), 3)))
        cur[:, 0] += flex
        cur[:, 1] += abd
        cur[:, 2] += twist


def _idle(tr: _Track, rng: np.random.Generator, arms: bool = True) -> None:
    t = tr.t
    tr.add("SpineMid", flex=_sway(t, rng, 1.5) - 0.8 * np.sin(2 * np.pi * 0.25 * t), abd=_sway(t, rng, 1.0))
    tr.add("SpineShoulder", flex=_sway(t, rng, 1.0))
    tr.add("Neck", flex=_sway(t, rng, 4.0), twist=_sway(t, rng, 6.0))
    if arms:
        for side in ("Left", "Right"):
            tr.add(f"Shoulder{side}", flex=_sway(t, rng, 3.0) + 3, abd=8 + _sway(t, rng, 2.0), twist=-10)
            tr.add(f"Elbow{side}", flex=12 + _sway(t, rng, 4.0))
            tr.add(f"Wrist{side}", flex=_sway(t, rng, 5.0))


def _standing(t: np.ndarray, rng: np.random.Generator) -> tuple[dict, np.ndarray, np.ndarray]:
    tr = _Track(t)
    _idle(tr, rng)
    D = t[-1]
    for side in ("Left", "Right"):
        tr.add(f"Knee{side}", flex=-4 + _sway(t, rng, 1.5))
        tr.add(f"Hip{side}", flex=2 + _sway(t, rng, 1.0))
        tr.add(f"Ankle{side}", flex=2)
    # segments scaled to the duration, jittered by the seed
    seg = lambda a, b: (a * D / 30.0 + rng.uniform(-0.3, 0.3), b * D / 30.0 + rng.uniform(-0.3, 0.3))
    a, b = seg(3, 9)  # wave right hand: arm up and out, forearm swings side to side
    e = _env(t, a, b, 1.2)
    tr.add("ShoulderRight", flex=25 * e, abd=95 * e, twist=75 * e + 28 * e * np.sin(2 * np.pi * 1.7 * (t - a)))
    tr.add("ElbowRight", flex=75 * e)
    a, b = seg(10, 14)  # reach forward with the left hand and come back
    e = _env(t, a, b, 1.6)
    tr.add("ShoulderLeft", flex=80 * e, abd=-5 * e)
    tr.add("ElbowLeft", flex=-8 * e)
    tr.add("SpineMid", flex=-8 * e)
    a, b = seg(15, 21)  # draw lines in the air with both hands
    e = _env(t, a, b, 1.2)
    ph = 2 * np.pi * 0.45 * (t - a)
    tr.add("ShoulderRight", flex=e * (65 + 15 * np.sin(ph)), abd=e * (10 + 22 * np.sin(0.5 * ph)))
    tr.add("ElbowRight", flex=e * (35 + 10 * np.cos(ph)))
    tr.add("ShoulderLeft", flex=e * (60 + 18 * np.sin(ph + 1.0)), abd=e * (5 + 10 * np.cos(0.5 * ph)))
    tr.add("ElbowLeft", flex=e * (40 + 10 * np.sin(ph)))
    a, b = seg(22, 26)  # beckon "come here" with the right hand
    e = _env(t, a, b, 1.0)
    tr.add("ShoulderRight", flex=45 * e, twist=20 * e)
    tr.add("ElbowRight", flex=e * (70 + 35 * np.sin(2 * np.pi * 1.2 * (t - a))))
    tr.add("WristRight", flex=e * 25 * np.sin(2 * np.pi * 1.2 * (t - a) - 0.5))
    a, _ = seg(26.5, 29)  # a side step to the subject's left and back
    step = _mj(t, a, a + 1.0) - _mj(t, a + 2.0, a + 3.0)
    lift = _env(t, a - 0.1, a + 1.1, 0.5) + _env(t, a + 1.9, a + 3.1, 0.5)
    tr.add("HipLeft", abd=12 * lift, flex=8 * lift)
    tr.add("KneeLeft", flex=-20 * lift)
    root = np.stack([0.25 * step + _sway(t, rng, 0.012), 0.004 * np.sin(2 * np.pi * 0.25 * t) - 0.01 * lift,
                     _sway(t, rng, 0.015)], axis=1)
    yaw = _sway(t, rng, 5.0, 0.03, 0.1)
    return tr.a, root, yaw


def _seated(t: np.ndarray, rng: np.random.Generator) -> tuple[dict, np.ndarray, np.ndarray]:
    tr = _Track(t)
    _idle(tr, rng)
    D = t[-1]
    tr.add("SpineMid", flex=-8)
    for side in ("Left", "Right"):
        tr.add(f"Hip{side}", flex=85 + _sway(t, rng, 2.0), abd=6 + _sway(t, rng, 2.0))
        tr.add(f"Knee{side}", flex=-88 + _sway(t, rng, 3.0))
        tr.add(f"Ankle{side}", flex=8)
        tr.add(f"Shoulder{side}", flex=30, abd=5)  # forearms over the desk
        tr.add(f"Elbow{side}", flex=55)
    seg = lambda a, b: (a * D / 30.0 + rng.uniform(-0.3, 0.3), b * D / 30.0 + rng.uniform(-0.3, 0.3))
    a, b = seg(4, 9)  # point forward-right
    e = _env(t, a, b, 1.2)
    tr.add("ShoulderRight", flex=45 * e, abd=15 * e)
    tr.add("ElbowRight", flex=-45 * e)
    a, b = seg(11, 16)  # wave with the left hand
    e = _env(t, a, b, 1.0)
    tr.add("ShoulderLeft", flex=20 * e, abd=70 * e, twist=70 * e + 25 * e * np.sin(2 * np.pi * 1.6 * (t - a)))
    tr.add("ElbowLeft", flex=40 * e)
    a, b = seg(18, 27)  # explain with both hands
    e = _env(t, a, b, 1.2)
    ph = 2 * np.pi * 0.7 * (t - a)
    for side, off in (("Left", 0.0), ("Right", 1.7)):
        tr.add(f"Shoulder{side}", flex=e * (15 + 12 * np.sin(ph + off)), abd=e * (10 + 8 * np.sin(0.6 * ph + off)))
        tr.add(f"Elbow{side}", flex=e * (20 + 15 * np.cos(ph + off)))
    a, b = seg(20, 25)  # tap the right foot
    e = _env(t, a, b, 0.6)
    tr.add("AnkleRight", flex=e * 12 * (1 + np.sin(2 * np.pi * 2.0 * (t - a))) / 2)
    root = np.stack([_sway(t, rng, 0.01), _sway(t, rng, 0.004), _sway(t, rng, 0.02)], axis=1)
    return tr.a, root, _sway(t, rng, 4.0, 0.03, 0.15)


def _stepping(t: np.ndarray, rng: np.random.Generator) -> tuple[dict, np.ndarray, np.ndarray]:
    tr = _Track(t)
    _idle(tr, rng, arms=False)
    f = rng.uniform(0.8, 0.95)  # strides per second
    on = _env(t, 1.5, t[-1] - 1.0, 1.5)
    ph = 2 * np.pi * f * t
    for side, off in (("Left", 0.0), ("Right", np.pi)):
        lift = np.maximum(np.sin(ph + off), 0.0) ** 1.5 * on
        tr.add(f"Hip{side}", flex=38 * lift + 2, abd=3)
        tr.add(f"Knee{side}", flex=-70 * lift - 4)
        tr.add(f"Ankle{side}", flex=10 * lift)
        tr.add(f"Shoulder{side}", flex=18 * on * np.sin(ph + off + np.pi) + 3, abd=10, twist=-10)
        tr.add(f"Elbow{side}", flex=25 + 12 * on * np.maximum(np.sin(ph + off + np.pi), 0))
    D = t[-1]
    move = 0.35 * (_mj(t, 0.25 * D, 0.4 * D) - _mj(t, 0.6 * D, 0.8 * D))
    root = np.stack([_sway(t, rng, 0.01), 0.015 * on * np.abs(np.sin(ph)) - 0.01 * on, -move], axis=1)
    yaw = 25 * np.sin(2 * np.pi * t / D) * on + _sway(t, rng, 3.0, 0.05, 0.2)
    return tr.a, root, yaw


ACTIVITIES = {"standing": _standing, "seated": _seated, "stepping": _stepping}


def generate_clean(
    activity: str,
    duration_s: float,
    rate_hz: float,
    bone_length: np.ndarray,
    placement: np.ndarray,
    seed: int = 0,
    *,
    subject_scale: float | None = None,
) -> Motion:
    """A clean ``KINECT_V2`` motion in camera space (m, s): ``activity`` for ``duration_s``.

    ``bone_length`` (24,) m is scaled by ``subject_scale`` (default: drawn from
    U(0.95, 1.05) with the seed) and made left/right symmetric; ``placement`` (3,) m is
    the camera-space SpineBase position the subject stands or sits at.
    """
    if activity not in ACTIVITIES:
        raise ValueError(f"unknown activity {activity!r}; known: {', '.join(ACTIVITIES)}")
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / float(rate_hz)
    drawn = rng.uniform(0.95, 1.05)  # always drawn, so a given scale leaves the motion's stream unchanged
    scale = drawn if subject_scale is None else float(subject_scale)
    L = np.asarray(bone_length, dtype=np.float64).copy()
    names = KINECT_V2.joint_names
    for i, (p, c) in enumerate(KINECT_V2.bones):  # symmetric: mean of left and right
        if "Left" in names[c]:
            k = next(k for k, (pp, cc) in enumerate(KINECT_V2.bones) if names[cc] == names[c].replace("Left", "Right"))
            L[i] = L[k] = 0.5 * (L[i] + L[k])
    angles, root, yaw = ACTIVITIES[activity](t, rng)
    X = pose_body(angles, root, yaw, L * scale)
    flip = np.array([-1.0, 1.0, -1.0])  # 180 deg about y: facing the sensor
    X = X * flip + np.asarray(placement, dtype=np.float64)
    m = Motion.from_positions(X, KINECT_V2, rate_hz)
    m.meta.update({"activity": activity, "seed": seed, "subject_scale": scale, "generator": "streamfix.sim.body"})
    return m
