"""Which joints of a layout are the legs, the shoulders and the mirror images of each other.

The real-sensor stages (a supporting foot stays on the floor, left/right symmetry of bone
lengths, left/right swaps) need to know what a joint *is*, not only how bones connect.
:func:`limb_layout` reads it from joint names, so one rule set covers Kinect v1 (UI-PRMD's
``LHip``), Kinect v2 (``HipLeft``), Azure Kinect (``HIP_LEFT``), BlazePose (``left_hip``)
and CMU/Mixamo BVH (``LeftHip`` / ``LeftUpLeg``). A layout without legs gets ``legs`` None:
the stages that need them simply do nothing.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .skeletons import Skeleton

__all__ = ["LimbLayout", "limb_layout", "mirror_index", "mirror_bones", "limb_groups"]

# candidate names per part, normalised (lower case, no '_', ' ', '.'); "{s}" = side word
_PARTS: dict[str, tuple[str, ...]] = {
    "hip": ("hip{s}", "{c}hip", "{s}hip", "{s}upleg", "{c}upleg", "{s}thigh"),
    "knee": ("knee{s}", "{c}knee", "{s}knee", "{s}leg", "{c}leg", "{s}shin"),
    "ankle": ("ankle{s}", "{c}ankle", "{s}ankle"),
    "foot": ("foot{s}", "{c}foot", "{s}foot", "{s}toe", "{s}toebase", "{c}toe", "{s}footindex", "{s}toes"),
    "shoulder": ("shoulder{s}", "{c}shoulder", "{s}shoulder", "{s}arm"),
}


@dataclass(frozen=True)
class LimbLayout:
    """Joint indices of one layout's limbs.

    legs: ``(2, 4)`` int, rows left/right, columns hip, knee, ankle, foot (the foot
    column repeats the ankle when the layout has no foot joint), or None.
    shoulders: ``(2,)`` int (left, right) or None. mirror: ``(J,)`` int, the left/right
    mirror image of each joint (itself for midline joints).
    """

    legs: np.ndarray | None
    shoulders: np.ndarray | None
    mirror: np.ndarray


def _norm(name: str) -> str:
    return re.sub(r"[\s_.\-]", "", name).lower()


def _find(index: dict[str, int], part: str, side: str, taken: set[int]) -> int | None:
    word, char = ("left", "l") if side == "L" else ("right", "r")
    for pattern in _PARTS[part]:
        j = index.get(pattern.format(s=word, c=char))
        if j is not None and j not in taken:
            return j
    return None


def _swap_side(name: str) -> str:
    """The mirror name: Left<->Right in any case, and a leading L/R (or l/r) side letter."""
    table = {"left": "right", "right": "left", "Left": "Right", "Right": "Left", "LEFT": "RIGHT", "RIGHT": "LEFT"}
    out = re.sub(r"left|right|Left|Right|LEFT|RIGHT", lambda m: table[m.group(0)], name)
    if out != name:
        return out
    m = re.match(r"^([LRlr])(?=[A-Z_]|hand|hip|up|leg|foot|toe|arm|fore|collar|thumb|fingers)", name)
    if m:
        other = {"L": "R", "R": "L", "l": "r", "r": "l"}[m.group(1)]
        return other + name[1:]
    return name


def mirror_index(skeleton: Skeleton) -> np.ndarray:
    """``(J,)`` index of each joint's left/right mirror image (itself where there is none)."""
    index = {n: i for i, n in enumerate(skeleton.joint_names)}
    return np.array([index.get(_swap_side(n), i) for i, n in enumerate(skeleton.joint_names)], dtype=np.intp)


def limb_groups(skeleton: Skeleton) -> list[tuple[np.ndarray, np.ndarray]]:
    """Mirror pairs of whole limbs: ``[(left joints, their mirror images), ...]``.

    A limb is the set of sided joints hanging from one sided joint whose parent is on
    the midline (Kinect v2: ShoulderLeft..HandTipLeft/ThumbLeft, HipLeft..FootLeft); the
    second array holds each joint's mirror, in the same order. Layouts without a tree
    (no parent for some joint) or without mirrors give no groups.
    """
    m = mirror_index(skeleton)
    n = len(skeleton.joint_names)
    parent = np.full(n, -1)
    for a, b in skeleton.bones:
        parent[b] = a
    sided = m != np.arange(n)
    root = np.full(n, -1)
    for j in range(n):  # walk up to the topmost sided ancestor (a few steps per joint)
        if not sided[j]:
            continue
        r, k = j, parent[j]
        while k >= 0 and sided[k]:
            r, k = k, parent[k]
        root[j] = r
    groups = []
    for r in np.unique(root[root >= 0]):
        if r < m[r]:  # each pair once, from its lower-indexed side
            a = np.flatnonzero(root == r)
            b = m[a]
            if (root[b] == m[r]).all():
                groups.append((a.astype(np.intp), b.astype(np.intp)))
    return groups


@lru_cache(maxsize=64)
def mirror_bones(skeleton: Skeleton) -> np.ndarray:
    """``(B,)`` index of each bone's left/right counterpart (itself for midline bones); cached
    per skeleton (the engine's window stages read it every window), read-only."""
    m = mirror_index(skeleton)
    index = {(a, b): k for k, (a, b) in enumerate(skeleton.bones)}
    out = np.array([index.get((int(m[a]), int(m[b])), k) for k, (a, b) in enumerate(skeleton.bones)], dtype=np.intp)
    out.setflags(write=False)
    return out


def limb_layout(skeleton: Skeleton) -> LimbLayout:
    """Legs, shoulders and mirror pairs of ``skeleton``, found from its joint names."""
    index = {_norm(n): i for i, n in enumerate(skeleton.joint_names)}
    legs = []
    for side in ("L", "R"):
        taken: set[int] = set()
        row = []
        for part in ("hip", "knee", "ankle", "foot"):
            j = _find(index, part, side, taken)
            if j is None and part == "ankle":  # Mixamo: LeftFoot is the ankle, LeftToeBase the foot
                j = _find(index, "foot", side, taken)
            if j is None and part == "foot" and row:
                j = row[-1]  # no foot joint: the ankle is the lowest point
            if j is None:
                break
            taken.add(j)
            row.append(j)
        legs.append(row)
    leg_array = np.array(legs, dtype=np.intp) if all(len(r) == 4 for r in legs) else None
    sh = [_find(index, "shoulder", s, set()) for s in ("L", "R")]
    shoulders = np.array(sh, dtype=np.intp) if None not in sh else None
    return LimbLayout(leg_array, shoulders, mirror_index(skeleton))
