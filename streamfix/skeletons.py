"""Skeleton definitions: joint names and bone lists for the sensors streamfix reads.

A :class:`Skeleton` is what turns a ``(T, J, 3)`` array into a body: it names each
joint and lists the bones (pairs of joint indices) whose lengths the isometry term
keeps constant. The registry holds the built-in sensor layouts; skeletons read from
a BVH hierarchy or a C3D marker set are made on the fly and may be registered too.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Skeleton",
    "get_skeleton",
    "register_skeleton",
    "skeleton_names",
    "KINECT_V2",
    "AZURE_KINECT",
    "MEDIAPIPE_POSE",
    "BLAZEPOSE_33",
    "KINECT_V1_UIPRMD",
    "COCO_17",
    "CAMERA_SPACE_SKELETONS",
]


def _directed_cycle(n_joints: int, bones: tuple[tuple[int, int], ...]) -> list[int]:
    """The joints of one cycle of (parent, child) links, in order, or [] (Kahn's algorithm:
    joints left once every root-reachable one is ordered lie on or below a cycle)."""
    children: list[list[int]] = [[] for _ in range(n_joints)]
    parents_left = [0] * n_joints
    for a, b in bones:
        children[a].append(b)
        parents_left[b] += 1
    ready = [j for j in range(n_joints) if parents_left[j] == 0]
    while ready:
        j = ready.pop()
        for c in children[j]:
            parents_left[c] -= 1
            if parents_left[c] == 0:
                ready.append(c)
    left = {j for j in range(n_joints) if parents_left[j] > 0}
    if not left:
        return []
    parent_in_left = {b: a for a, b in bones if a in left and b in left}
    j, seen = next(iter(left)), []
    while j not in seen:  # walk up parents inside the remainder until a joint repeats
        seen.append(j)
        j = parent_in_left[j]
    return seen[seen.index(j):][::-1]


@dataclass(frozen=True)
class Skeleton:
    """A named joint layout and the bones that connect its joints.

    Attributes
    ----------
    name:
        Registry key, e.g. ``"kinect_v2"``; also sent on the wire so that a
        subscriber can look the layout up.
    joint_names:
        One name per joint, in array order.
    bones:
        ``(parent, child)`` joint-index pairs. Need not form a tree (MediaPipe's
        connection graph does not: a joint may have two parents), but the links may not
        form a cycle (ValueError naming it); for tree skeletons parents come first.
    """

    name: str
    joint_names: tuple[str, ...]
    bones: tuple[tuple[int, int], ...]
    _index: dict = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        names = tuple(self.joint_names)
        bones = tuple((int(a), int(b)) for a, b in self.bones)
        object.__setattr__(self, "joint_names", names)
        object.__setattr__(self, "bones", bones)
        if len(set(names)) != len(names):
            raise ValueError(f"skeleton {self.name!r}: joint names are not unique")
        for a, b in bones:
            if not (0 <= a < len(names) and 0 <= b < len(names)) or a == b:
                raise ValueError(
                    f"skeleton {self.name!r}: bone ({a}, {b}) does not join two of its "
                    f"{len(names)} joints"
                )
        cycle = _directed_cycle(len(names), bones)
        if cycle:
            path = " -> ".join(names[j] for j in cycle + cycle[:1])
            raise ValueError(f"skeleton {self.name!r}: its (parent, child) bones form a cycle ({path}); "
                             "every chain of parents must end at a root")
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(names)})

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_bones(self) -> int:
        return len(self.bones)

    @property
    def bone_array(self) -> np.ndarray:
        """Bones as an ``(B, 2)`` int array of (parent, child) joint indices."""
        return np.asarray(self.bones, dtype=np.intp).reshape(-1, 2)

    def index(self, joint_name: str) -> int:
        """Index of a joint by name; KeyError names the skeleton and the joint."""
        try:
            return self._index[joint_name]
        except KeyError:
            raise KeyError(f"skeleton {self.name!r} has no joint {joint_name!r}") from None

    def to_dict(self) -> dict:
        """Plain-data form (what the wire protocol's skeleton message carries)."""
        return {
            "name": self.name,
            "joint_names": list(self.joint_names),
            "bones": [list(b) for b in self.bones],
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Skeleton":
        return cls(data["name"], tuple(data["joint_names"]), tuple(tuple(b) for b in data["bones"]))

    @classmethod
    def from_parents(cls, name: str, joint_names, parents) -> "Skeleton":
        """A tree skeleton from one parent per joint: an index, a joint name, or None / -1 for a root.

        >>> Skeleton.from_parents("arm", ["shoulder", "elbow", "wrist"], [None, 0, "elbow"]).bones
        ((0, 1), (1, 2))
        """
        names = tuple(joint_names)
        parents = list(parents)
        if len(parents) != len(names):
            raise ValueError(f"skeleton {name!r}: {len(names)} joint names but {len(parents)} parents")
        index = {n: i for i, n in enumerate(names)}
        bones = []
        for child, parent in enumerate(parents):
            if parent is None or (isinstance(parent, (int, np.integer)) and parent < 0):
                continue
            if isinstance(parent, str):
                if parent not in index:
                    raise ValueError(f"skeleton {name!r}: joint {names[child]!r} has unknown parent {parent!r}")
                parent = index[parent]
            bones.append((int(parent), child))
        return cls(name, names, tuple(bones))


def _from_parents(name: str, joints: list[tuple[str, str | None]]) -> Skeleton:
    """Build a tree skeleton from ``(joint, parent)`` pairs listed in array order."""
    names = [j for j, _ in joints]
    index = {n: i for i, n in enumerate(names)}
    bones = [(index[p], index[j]) for j, p in joints if p is not None]
    return Skeleton(name, tuple(names), tuple(bones))


# Kinect v2 JointType order (Microsoft Kinect for Windows SDK 2.0): 25 joints, 24 bones.
KINECT_V2 = _from_parents(
    "kinect_v2",
    [
        ("SpineBase", None),
        ("SpineMid", "SpineBase"),
        ("Neck", "SpineShoulder"),
        ("Head", "Neck"),
        ("ShoulderLeft", "SpineShoulder"),
        ("ElbowLeft", "ShoulderLeft"),
        ("WristLeft", "ElbowLeft"),
        ("HandLeft", "WristLeft"),
        ("ShoulderRight", "SpineShoulder"),
        ("ElbowRight", "ShoulderRight"),
        ("WristRight", "ElbowRight"),
        ("HandRight", "WristRight"),
        ("HipLeft", "SpineBase"),
        ("KneeLeft", "HipLeft"),
        ("AnkleLeft", "KneeLeft"),
        ("FootLeft", "AnkleLeft"),
        ("HipRight", "SpineBase"),
        ("KneeRight", "HipRight"),
        ("AnkleRight", "KneeRight"),
        ("FootRight", "AnkleRight"),
        ("SpineShoulder", "SpineMid"),
        ("HandTipLeft", "HandLeft"),
        ("ThumbLeft", "WristLeft"),
        ("HandTipRight", "HandRight"),
        ("ThumbRight", "WristRight"),
    ],
)

# Azure Kinect Body Tracking SDK k4abt_joint_id_t order: 32 joints, 31 bones.
AZURE_KINECT = _from_parents(
    "azure_kinect",
    [
        ("PELVIS", None),
        ("SPINE_NAVEL", "PELVIS"),
        ("SPINE_CHEST", "SPINE_NAVEL"),
        ("NECK", "SPINE_CHEST"),
        ("CLAVICLE_LEFT", "SPINE_CHEST"),
        ("SHOULDER_LEFT", "CLAVICLE_LEFT"),
        ("ELBOW_LEFT", "SHOULDER_LEFT"),
        ("WRIST_LEFT", "ELBOW_LEFT"),
        ("HAND_LEFT", "WRIST_LEFT"),
        ("HANDTIP_LEFT", "HAND_LEFT"),
        ("THUMB_LEFT", "WRIST_LEFT"),
        ("CLAVICLE_RIGHT", "SPINE_CHEST"),
        ("SHOULDER_RIGHT", "CLAVICLE_RIGHT"),
        ("ELBOW_RIGHT", "SHOULDER_RIGHT"),
        ("WRIST_RIGHT", "ELBOW_RIGHT"),
        ("HAND_RIGHT", "WRIST_RIGHT"),
        ("HANDTIP_RIGHT", "HAND_RIGHT"),
        ("THUMB_RIGHT", "WRIST_RIGHT"),
        ("HIP_LEFT", "PELVIS"),
        ("KNEE_LEFT", "HIP_LEFT"),
        ("ANKLE_LEFT", "KNEE_LEFT"),
        ("FOOT_LEFT", "ANKLE_LEFT"),
        ("HIP_RIGHT", "PELVIS"),
        ("KNEE_RIGHT", "HIP_RIGHT"),
        ("ANKLE_RIGHT", "KNEE_RIGHT"),
        ("FOOT_RIGHT", "ANKLE_RIGHT"),
        ("HEAD", "NECK"),
        ("NOSE", "HEAD"),
        ("EYE_LEFT", "HEAD"),
        ("EAR_LEFT", "HEAD"),
        ("EYE_RIGHT", "HEAD"),
        ("EAR_RIGHT", "HEAD"),
    ],
)

_MEDIAPIPE_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner",
    "right_eye", "right_eye_outer", "left_ear", "right_ear", "mouth_left",
    "mouth_right", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index",
    "right_index", "left_thumb", "right_thumb", "left_hip", "right_hip",
    "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)
# MediaPipe/BlazePose POSE_CONNECTIONS (a graph, not a tree): 35 edges.
_MEDIAPIPE_EDGES = (
    (0, 1), (1, 2), (2, 3), (3, 7), (0, 4), (4, 5), (5, 6), (6, 8), (9, 10),
    (11, 12), (11, 13), (13, 15), (15, 17), (15, 19), (15, 21), (17, 19),
    (12, 14), (14, 16), (16, 18), (16, 20), (16, 22), (18, 20), (11, 23),
    (12, 24), (23, 24), (23, 25), (24, 26), (25, 27), (26, 28), (27, 29),
    (28, 30), (29, 31), (30, 32), (27, 31), (28, 32),
)
MEDIAPIPE_POSE = Skeleton("mediapipe_pose", _MEDIAPIPE_NAMES, _MEDIAPIPE_EDGES)
#: BlazePose-33 is MediaPipe Pose's layout (same 33 keypoints, same order): one skeleton, two names in code.
BLAZEPOSE_33 = MEDIAPIPE_POSE

# Kinect v1 as released in UI-PRMD (Vakanski et al., Data 2018): 22 joints, 21 bones, rebuilt
# from the release's local offsets; HeadTip is where the sensor's head joint is.
KINECT_V1_UIPRMD = _from_parents(
    "kinect_v1_uiprmd",
    [
        ("Waist", None), ("Spine", "Waist"), ("Chest", "Spine"), ("Neck", "Chest"),
        ("Head", "Neck"), ("HeadTip", "Head"),
        ("LCollar", "Chest"), ("LShoulder", "LCollar"), ("LElbow", "LShoulder"), ("LWrist", "LElbow"),
        ("RCollar", "Chest"), ("RShoulder", "RCollar"), ("RElbow", "RShoulder"), ("RWrist", "RElbow"),
        ("LHip", "Waist"), ("LKnee", "LHip"), ("LAnkle", "LKnee"), ("LFoot", "LAnkle"),
        ("RHip", "Waist"), ("RKnee", "RHip"), ("RAnkle", "RKnee"), ("RFoot", "RAnkle"),
    ],
)

# COCO-17 keypoints (pose estimators: OpenPose/MMPose/YOLO-pose 3D lifts), the COCO skeleton's 16 limb edges
# plus the shoulder-hip sides; a graph, not a tree.
COCO_17 = Skeleton(
    "coco17",
    ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
     "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
     "right_knee", "left_ankle", "right_ankle"),
    ((0, 1), (0, 2), (1, 3), (2, 4), (5, 6), (5, 7), (7, 9), (6, 8), (8, 10), (5, 11), (6, 12), (11, 12),
     (11, 13), (13, 15), (12, 14), (14, 16)),
)

_REGISTRY: dict[str, Skeleton] = {
    s.name: s for s in (KINECT_V2, AZURE_KINECT, MEDIAPIPE_POSE, KINECT_V1_UIPRMD, COCO_17)
}


def register_skeleton(skeleton: Skeleton, *, replace: bool = False) -> Skeleton:
    """Add a skeleton (e.g. one read from a BVH file) to the registry."""
    existing = _REGISTRY.get(skeleton.name)
    if existing is not None and existing != skeleton and not replace:
        raise ValueError(f"a different skeleton named {skeleton.name!r} is already registered")
    _REGISTRY[skeleton.name] = skeleton
    return skeleton


def get_skeleton(name: str) -> Skeleton:
    """Look a skeleton up by name; the error lists the known names."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(
            f"unknown skeleton {name!r}; known skeletons: {', '.join(sorted(_REGISTRY))}"
        ) from None


CAMERA_SPACE_SKELETONS = ("kinect_v2", "kinect_v1_uiprmd", "azure_kinect", "coco17", "mediapipe_pose")
"""Layouts of depth sensors and pose estimators, whose streams come in the sensor's camera space
(the sensor at the origin, metres): what ``streamfix.core.ray_depth`` needs to know where a
joint's camera ray runs. Optical markers and BVH takes are in a room's coordinates."""


def skeleton_names() -> list[str]:
    return sorted(_REGISTRY)
