"""Retarget CMU-family BVH skeletons (CMU 131_*, Xia et al.) onto the Kinect v2 layout.

:func:`bvh_to_kinect_v2` maps the global joint positions of a BVH motion (from
:func:`streamfix.io.bvh.read_bvh`) to the 25 Kinect v2 joints. It works on positions
only (no rotations needed), so it also applies after slicing or resampling.

Mapping table (first BVH name found wins; a ``prefix:`` such as ``mixamorig:`` is
ignored). L/R below stand for Left/Right (``L``/``R``, ``l``/``r`` for the short
CMU names):

================  =================================================================
Kinect v2         from the BVH skeleton
================  =================================================================
SpineBase         ``Hips`` (the root, pelvis centre)
SpineShoulder     the ``Head`` joint's parent (CMU ``Neck``, Xia ``Neck1``): the
                  base of the neck at shoulder height
SpineMid          the point at 58 % of the spine's arc length from ``Hips`` to
                  SpineShoulder, following the spine joints (Kinect v2's median
                  SpineBase-SpineMid : SpineMid-SpineShoulder is 0.30 : 0.22 m,
                  measured on ../shared/data/kinect_v2)
Neck              60 % of the way from SpineShoulder to the BVH ``Head`` joint
Head              head centre: midway between ``Head`` and its End Site when the
                  motion carries End Sites of non-zero length, else ``Head`` +
                  0.6 (``Head`` - SpineShoulder) (extrapolated along the neck)
ShoulderL         ``LeftArm`` | ``LeftShoulder``  (Xia's ``LeftShoulder`` is the
                  clavicle root; it is used only when there is no ``LeftArm``)
ElbowL            ``LeftForeArm`` | ``LeftElbow``
WristL            ``LeftWrist`` | ``LeftHand``
HandL             ``LFingers`` | ``LeftHandIndex1`` | ``LeftFingerBase`` | ``lhand``
                  (mid-hand, about 4 cm from the wrist)
HandTipL          the fingers' End Site when non-degenerate, else HandL + 1.5
                  (HandL - WristL)
ThumbL            the thumb's End Site when non-degenerate, else WristL +
                  1.5 |HandL - WristL| * unit(unit(HandL - WristL) + forward),
                  forward = unit(up x right) of the torso (CMU's own thumb End
                  Sites point 45 deg between hand and body-forward in rest pose)
HipL              ``LeftUpLeg`` | ``LeftHip``
KneeL             ``LeftLeg`` | ``LeftKnee``
AnkleL            ``LeftFoot`` | ``LeftAnkle``
FootL             ``LeftToeBase`` | ``LeftToe`` (ball of the foot)
================  =================================================================

Coordinates are kept (BVH y-up, metres) unless ``to_camera=True``: then the motion
is turned 180 deg about y so that a subject facing +z (BVH convention) faces the
sensor, and shifted so that the first frame's SpineBase sits at
``CAMERA_SPINE_BASE`` = (0, -0.35, 2.7) m, the median SpineBase of the standing
Kinect v2 recordings. Bone lengths are the BVH subject's unless ``bone_lengths`` asks
for others (directions kept, lengths set, outwards from SpineBase).
"""
from __future__ import annotations

import numpy as np

from ..motion import Motion
from ..skeletons import KINECT_V2, Skeleton

__all__ = ["bvh_to_kinect_v2", "CAMERA_SPINE_BASE", "KINECT_FROM_BVH"]

CAMERA_SPINE_BASE = np.array([0.0, -0.35, 2.7])
SPINE_MID_FRACTION = 0.58  # 0.30 / (0.30 + 0.22), Kinect v2 medians
NECK_FRACTION = 0.6
HAND_TIP_EXTENSION = 1.5
THUMB_LENGTH = 1.5

_SIDE = {
    "Left": {"L": "Left", "l": "L", "h": "l"},
    "Right": {"L": "Right", "l": "R", "h": "r"},
}
# Kinect joint (without side) -> candidate BVH names; {L} Left/Right, {l} L/R, {h} l/r
_SIDED = {
    "Shoulder": ["{L}Arm", "{L}Shoulder"],
    "Elbow": ["{L}ForeArm", "{L}Elbow"],
    "Wrist": ["{L}Wrist", "{L}Hand"],
    "Hand": ["{l}Fingers", "{L}HandIndex1", "{L}FingerBase", "{h}hand"],
    "Hip": ["{L}UpLeg", "{L}Hip"],
    "Knee": ["{L}Leg", "{L}Knee"],
    "Ankle": ["{L}Foot", "{L}Ankle"],
    "Foot": ["{L}ToeBase", "{L}Toe"],
}
_THUMB = ["{l}Thumb", "{L}HandThumb1", "{L}Thumb"]
KINECT_FROM_BVH = {f"{k}{side}": [c.format(**_SIDE[side]) for c in v] for side in _SIDE for k, v in _SIDED.items()}


def _strip(name: str) -> str:
    return name.split(":")[-1]


def _find(skel: Skeleton, candidates: list[str], what: str) -> int:
    names = {_strip(n): i for i, n in enumerate(skel.joint_names)}
    for c in candidates:
        if c in names:
            return names[c]
    raise ValueError(
        f"cannot retarget {skel.name!r} to kinect_v2: no joint for {what} (looked for {', '.join(candidates)})"
    )


def _end_site(motion: Motion, joint: int, min_length: float = 1e-3) -> np.ndarray | None:
    """Positions of ``joint``'s End Site if the motion carries one of non-zero length."""
    name = motion.skeleton.joint_names[joint] + "_End"
    if name not in motion.skeleton.joint_names:
        return None
    e = motion.positions[:, motion.skeleton.index(name)]
    if np.nanmedian(np.linalg.norm(e - motion.positions[:, joint], axis=-1)) < min_length:
        return None
    return e


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _chain_point(X: np.ndarray, chain: list[int], fraction: float) -> np.ndarray:
    """Point at ``fraction`` of the arc length along joints ``chain`` (T,3); weights from median lengths."""
    seg = np.nanmedian(np.linalg.norm(np.diff(X[:, chain], axis=1), axis=-1), axis=0)  # (len-1,)
    target = fraction * seg.sum()
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    k = int(np.clip(np.searchsorted(cum, target, side="right") - 1, 0, len(seg) - 1))
    s = 0.0 if seg[k] <= 0 else (target - cum[k]) / seg[k]
    return (1 - s) * X[:, chain[k]] + s * X[:, chain[k + 1]]


def _reproportion(X: np.ndarray, bone_lengths: np.ndarray) -> np.ndarray:
    """Keep every bone's direction, set its length: walk the Kinect tree from SpineBase."""
    L = np.asarray(bone_lengths, dtype=np.float64)
    if L.shape != (KINECT_V2.n_bones,):
        raise ValueError(f"bone_lengths must be ({KINECT_V2.n_bones},) metres in KINECT_V2.bones order, got {L.shape}")
    out = X.copy()
    done = {0}
    pending = list(enumerate(KINECT_V2.bones))
    while pending:
        rest = []
        for k, (p, c) in pending:
            if p in done:
                out[:, c] = out[:, p] + L[k] * _unit(X[:, c] - X[:, p])
                done.add(c)
            else:
                rest.append((k, (p, c)))
        pending = rest
    return out


def bvh_to_kinect_v2(motion: Motion, *, to_camera: bool = False, bone_lengths: np.ndarray | None = None) -> Motion:
    """Map a CMU-family BVH motion onto the 25 ``KINECT_V2`` joints (see the module table).

    ``bone_lengths`` (24,) m in ``KINECT_V2.bones`` order, if given, re-proportions the
    result: every bone keeps its direction per frame and gets that length (e.g. a real
    Kinect subject's medians), built outwards from SpineBase.
    """
    skel = motion.skeleton
    X = motion.positions
    T = motion.n_frames
    parents = {c: p for p, c in skel.bones}
    out = np.full((T, KINECT_V2.n_joints, 3), np.nan)
    K = KINECT_V2.index

    hips = _find(skel, ["Hips", "hip", "Hip", "pelvis", "Pelvis"], "SpineBase (Hips)")
    head = _find(skel, ["Head", "head"], "Head")
    if head not in parents:
        raise ValueError(f"cannot retarget {skel.name!r}: Head has no parent joint")
    spine_shoulder = parents[head]
    chain = [spine_shoulder]
    while chain[-1] != hips:
        if chain[-1] not in parents:
            raise ValueError(f"cannot retarget {skel.name!r}: Head is not below Hips in the hierarchy")
        chain.append(parents[chain[-1]])
    chain = chain[::-1]

    out[:, K("SpineBase")] = X[:, hips]
    out[:, K("SpineShoulder")] = X[:, spine_shoulder]
    out[:, K("SpineMid")] = _chain_point(X, chain, SPINE_MID_FRACTION) if len(chain) > 1 else X[:, hips]
    neck_dir = X[:, head] - X[:, spine_shoulder]
    out[:, K("Neck")] = X[:, spine_shoulder] + NECK_FRACTION * neck_dir
    head_end = _end_site(motion, head)
    out[:, K("Head")] = (
        0.5 * (X[:, head] + head_end) if head_end is not None else X[:, head] + NECK_FRACTION * neck_dir
    )
    for side in ("Left", "Right"):
        for kj, candidates in _SIDED.items():
            idx = _find(skel, [c.format(**_SIDE[side]) for c in candidates], f"{kj}{side}")
            out[:, K(f"{kj}{side}")] = X[:, idx]

    up = out[:, K("SpineShoulder")] - out[:, K("SpineBase")]
    right = out[:, K("ShoulderRight")] - out[:, K("ShoulderLeft")]
    forward = _unit(np.cross(up, right))
    for side in ("Left", "Right"):
        hand_idx = _find(skel, [c.format(**_SIDE[side]) for c in _SIDED["Hand"]], f"Hand{side}")
        wrist = out[:, K(f"Wrist{side}")]
        hand = out[:, K(f"Hand{side}")]
        h = hand - wrist
        tip = _end_site(motion, hand_idx)
        out[:, K(f"HandTip{side}")] = tip if tip is not None else hand + HAND_TIP_EXTENSION * h
        thumb_end = None
        try:
            thumb_idx = _find(skel, [c.format(**_SIDE[side]) for c in _THUMB], f"Thumb{side}")
            thumb_end = _end_site(motion, thumb_idx)
        except ValueError:
            pass
        if thumb_end is None:
            hl = np.linalg.norm(h, axis=-1, keepdims=True)
            thumb_end = wrist + THUMB_LENGTH * hl * _unit(_unit(h) + forward)
        out[:, K(f"Thumb{side}")] = thumb_end

    if bone_lengths is not None:
        out = _reproportion(out, bone_lengths)
    if to_camera:
        flip = np.array([-1.0, 1.0, -1.0])  # 180 deg about y
        out = out * flip
        out = out - out[0, K("SpineBase")] + CAMERA_SPINE_BASE

    conf = np.where(np.isfinite(out).all(axis=2), motion.confidence.min(axis=1, keepdims=True), 0.0)
    meta = dict(motion.meta)
    meta.pop("bone_lengths", None)
    meta["retargeted_from"] = skel.name
    meta["to_camera"] = to_camera
    return Motion(out, conf, motion.timestamps.copy(), motion.rate_hz, KINECT_V2, meta=meta)
