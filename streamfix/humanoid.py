"""A skeleton as an animation rig: rest pose, rotation nodes, and Unity humanoid bone names.

BVH files and VMC (the avatar protocol of Unity tools) describe a body as a hierarchy of
nodes, each with a rest offset from its parent and a rotation per frame
(:mod:`streamfix.core.bone_rotations`). :func:`build_rig` makes that hierarchy for a
tree :class:`~streamfix.skeletons.Skeleton`:

* **Nodes**: one per joint, named as the joint, plus one zero-length *branch* node for
  every non-primary child of a joint with several children (named ``<parent>_<child>``,
  like CMU's ``LHipJoint``/``LeftCollar``). Each node then aims at one bone, so forward
  kinematics reproduces every joint exactly (bone lengths permitting), while the joint's
  own node still takes its twist from its other children (hips from the hip joints, a
  chest from the shoulders). The primary child is the midline one (the spine above the
  hips, the neck above the chest), else the first in joint order.
* **Rest pose: a T-pose** built from the bone lengths (the median over the frames of a
  motion, :func:`median_bone_lengths`), in a right-handed, y-up frame with the body
  facing +z and its left side towards +x: spine, neck and head up; hips and arms
  (clavicle, shoulder and everything below it) straight out sideways; thighs and shins
  down; feet and toes forward. Each joint is classed from :func:`streamfix.limbs.limb_layout`
  (hips, knees, ankles, feet, shoulders, mirror pairs) and the tree. A T-pose is what
  avatar receivers expect: a VRM/Unity humanoid in T-pose has identity local rotations,
  so the rotations solved against this rest pose drive such an avatar directly. A skeleton
  whose legs and shoulders cannot be found from its joint names gets the directions of a
  reference frame instead (``reference``, e.g. the first frame of the motion).

:func:`unity_bone_map` names the nodes with Unity ``HumanBodyBones`` (what VMC sends); see
its table.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .core.bone_rotations import parent_array, subtree_mask, topological_order
from .limbs import limb_layout
from .skeletons import Skeleton

__all__ = ["Rig", "build_rig", "t_pose_directions", "median_bone_lengths", "unity_bone_map", "UNITY_BONE_CANDIDATES"]

UP, DOWN, FORWARD = np.array([0.0, 1.0, 0.0]), np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, 1.0])
LEFT = np.array([1.0, 0.0, 0.0])  # the body's left in the rest frame (right-handed, y up, facing +z)


@dataclass(frozen=True)
class Rig:
    """A rotation hierarchy over a skeleton's joints (see module doc).

    names ``(N,)`` node names; joints ``(N,)`` the skeleton joint each node sits at;
    parents ``(N,)`` parent node (-1 for the root); offsets ``(N, 3)`` rest offsets in
    metres; primary: node -> the node whose direction it reproduces exactly.
    """

    skeleton: Skeleton
    names: tuple[str, ...]
    joints: np.ndarray
    parents: np.ndarray
    offsets: np.ndarray
    primary: dict

    def node_positions(self, positions: np.ndarray) -> np.ndarray:
        """``(T, N, 3)`` node positions from joint positions ``(T, J, 3)`` (branch nodes sit at their joint)."""
        return np.asarray(positions)[:, self.joints]

    def node(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"rig of skeleton {self.skeleton.name!r} has no node {name!r}") from None


def median_bone_lengths(positions: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """``(B,)`` median length (metres) of each bone over the frames where both ends are finite."""
    b = skeleton.bone_array
    lengths = np.linalg.norm(positions[:, b[:, 1]] - positions[:, b[:, 0]], axis=2)
    if not np.isfinite(lengths).any(axis=0).all():
        missing = [skeleton.joint_names[c] for (p, c), ok in zip(b, np.isfinite(lengths).any(axis=0)) if not ok]
        raise ValueError(f"no frame shows the bone to {', '.join(missing)}: its length is unknown")
    return np.nanmedian(lengths, axis=0)


def t_pose_directions(skeleton: Skeleton) -> np.ndarray | None:
    """``(J, 3)`` unit rest direction of the bone ending at each joint (root: zeros), or None.

    None when :func:`~streamfix.limbs.limb_layout` finds no legs or no shoulders.
    """
    parents = parent_array(skeleton.bone_array, skeleton.n_joints)
    layout = limb_layout(skeleton)
    if layout.legs is None or layout.shoulders is None:
        return None
    sided = layout.mirror != np.arange(skeleton.n_joints)
    dirs = np.tile(UP, (skeleton.n_joints, 1))
    for side, sign in ((0, 1.0), (1, -1.0)):
        hip, knee, ankle, foot = layout.legs[side]
        leg = subtree_mask(parents, hip)
        dirs[leg] = DOWN
        dirs[hip] = sign * LEFT
        if foot != ankle:
            dirs[subtree_mask(parents, foot)] = FORWARD
        shoulder = layout.shoulders[side]
        arm = subtree_mask(parents, shoulder)
        k = parents[shoulder]
        while k >= 0 and sided[k]:  # clavicles above the shoulder
            arm[k] = True
            k = parents[k]
        dirs[arm] = sign * LEFT
    dirs[parents < 0] = 0.0
    return dirs


def build_rig(skeleton: Skeleton, bone_lengths: np.ndarray, reference: np.ndarray | None = None) -> Rig:
    """The rig of a tree skeleton with a T-pose rest pose (see module doc).

    ``bone_lengths`` ``(B,)`` metres in the skeleton's bone order; ``reference`` ``(J, 3)``
    a pose whose bone directions are the rest pose when no T-pose can be built.
    """
    parents = parent_array(skeleton.bone_array, skeleton.n_joints)
    lengths = np.zeros(skeleton.n_joints)
    lengths[skeleton.bone_array[:, 1]] = np.asarray(bone_lengths, dtype=np.float64)
    directions = t_pose_directions(skeleton)
    if directions is None:
        if reference is None:
            raise ValueError(
                f"skeleton {skeleton.name!r}: no legs/shoulders recognised from its joint names, so no T-pose; "
                "pass a reference pose")
        ref = np.asarray(reference, dtype=np.float64)
        rel = np.zeros_like(ref)
        rel[parents >= 0] = ref[parents >= 0] - ref[parents[parents >= 0]]
        norm = np.linalg.norm(rel, axis=1, keepdims=True)
        directions = np.where(norm > 0, rel / np.where(norm > 0, norm, 1.0), 0.0)
    joint_offsets = directions * lengths[:, None]
    mirror = limb_layout(skeleton).mirror
    children: list[list[int]] = [[] for _ in range(skeleton.n_joints)]
    for p, c in skeleton.bones:
        children[p].append(c)
    names: list[str] = []
    joints: list[int] = []
    node_parents: list[int] = []
    offsets: list[np.ndarray] = []
    primary: dict[int, int] = {}
    node_of: dict[int, int] = {}

    def add(name: str, joint: int, parent: int, offset: np.ndarray) -> int:
        names.append(name)
        joints.append(joint)
        node_parents.append(parent)
        offsets.append(offset)
        return len(names) - 1

    for j in topological_order(parents):
        p = parents[j]
        if p < 0:
            node_of[j] = add(skeleton.joint_names[j], j, -1, np.zeros(3))
            continue
        kids = children[p]
        first = next((c for c in kids if mirror[c] == c), kids[0])
        parent_node = node_of[p]
        if j != first:  # a branch node at the parent aims at this child
            parent_node = add(f"{skeleton.joint_names[p]}_{skeleton.joint_names[j]}", p, parent_node, np.zeros(3))
        node_of[j] = add(skeleton.joint_names[j], j, parent_node, joint_offsets[j])
        if j == first:
            primary[node_of[p]] = node_of[j]
    return Rig(skeleton, tuple(names), np.array(joints, dtype=np.intp), np.array(node_parents, dtype=np.intp),
               np.array(offsets), primary)


# Unity HumanBodyBones -> joint names that play that part, first match wins; a joint already
# taken by an earlier bone is skipped (CMU's LeftShoulder is the upper arm; Xia's/Mixamo's,
# with a LeftArm below it, is the clavicle). Columns: Kinect v2, Azure Kinect, Kinect v1
# (UI-PRMD), CMU BVH, Xia/Mixamo BVH.
UNITY_BONE_CANDIDATES: dict[str, tuple[str, ...]] = {
    "Spine": ("SpineMid", "SPINE_NAVEL", "Spine", "Chest"),
    "Chest": ("SpineShoulder", "SPINE_CHEST", "Chest", "Chest2", "Spine1"),
    "Neck": ("Neck", "NECK"),
    "Head": ("Head", "HEAD"),
    "LeftUpperArm": ("ShoulderLeft", "SHOULDER_LEFT", "LShoulder", "LeftArm", "LeftShoulder"),
    "RightUpperArm": ("ShoulderRight", "SHOULDER_RIGHT", "RShoulder", "RightArm", "RightShoulder"),
    "LeftShoulder": ("CLAVICLE_LEFT", "LCollar", "LeftCollar", "LeftShoulder"),
    "RightShoulder": ("CLAVICLE_RIGHT", "RCollar", "RightCollar", "RightShoulder"),
    "LeftLowerArm": ("ElbowLeft", "ELBOW_LEFT", "LElbow", "LeftElbow", "LeftForeArm"),
    "RightLowerArm": ("ElbowRight", "ELBOW_RIGHT", "RElbow", "RightElbow", "RightForeArm"),
    "LeftHand": ("WristLeft", "WRIST_LEFT", "LWrist", "LeftWrist", "LeftHand"),
    "RightHand": ("WristRight", "WRIST_RIGHT", "RWrist", "RightWrist", "RightHand"),
    "LeftUpperLeg": ("HipLeft", "HIP_LEFT", "LHip", "LeftHip", "LeftUpLeg"),
    "RightUpperLeg": ("HipRight", "HIP_RIGHT", "RHip", "RightHip", "RightUpLeg"),
    "LeftLowerLeg": ("KneeLeft", "KNEE_LEFT", "LKnee", "LeftKnee", "LeftLeg"),
    "RightLowerLeg": ("KneeRight", "KNEE_RIGHT", "RKnee", "RightKnee", "RightLeg"),
    "LeftFoot": ("AnkleLeft", "ANKLE_LEFT", "LAnkle", "LeftAnkle", "LeftFoot"),
    "RightFoot": ("AnkleRight", "ANKLE_RIGHT", "RAnkle", "RightAnkle", "RightFoot"),
    "LeftToes": ("FootLeft", "FOOT_LEFT", "LFoot", "LeftToe", "LeftToeBase"),
    "RightToes": ("FootRight", "FOOT_RIGHT", "RFoot", "RightToe", "RightToeBase"),
}


def unity_bone_map(rig: Rig) -> dict[str, int]:
    """Unity ``HumanBodyBones`` name -> rig node, for the bones this rig has.

    ``Hips`` is the root node. The others come from :data:`UNITY_BONE_CANDIDATES`
    (a ``prefix:`` such as ``mixamorig:`` is ignored). A layout without clavicle joints
    (Kinect v2) gets ``LeftShoulder``/``RightShoulder`` from the branch node that aims at
    the upper arm. Joints with no humanoid counterpart (hand tips, thumbs, face points) are
    left out; they still shape the solve. KeyError if the rig has no recognisable spine
    and limbs (fewer than the 15 bones Unity requires of a humanoid).
    """
    bare = {n.split(":")[-1]: k for k, n in enumerate(rig.names)}
    mapping = {"Hips": int(np.flatnonzero(rig.parents < 0)[0])}
    taken = set(mapping.values())
    for bone in ("Spine", "Chest", "Neck", "Head", "LeftUpperArm", "RightUpperArm", "LeftShoulder", "RightShoulder",
                 "LeftLowerArm", "RightLowerArm", "LeftHand", "RightHand", "LeftUpperLeg", "RightUpperLeg",
                 "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot", "LeftToes", "RightToes"):
        node = next((bare[n] for n in UNITY_BONE_CANDIDATES[bone] if n in bare and bare[n] not in taken), None)
        if node is None and bone.endswith("Shoulder"):
            arm = mapping.get(bone.replace("Shoulder", "UpperArm"))
            branch = rig.parents[arm] if arm is not None else -1
            if branch >= 0 and rig.parents[branch] >= 0 and rig.joints[branch] == rig.joints[rig.parents[branch]]:
                node = int(branch)  # the zero-length branch node above the upper arm
        if node is not None and node not in taken:
            mapping[bone] = node
            taken.add(node)
    required = {"Hips", "Spine", "Head", "LeftUpperArm", "RightUpperArm", "LeftLowerArm", "RightLowerArm", "LeftHand",
                "RightHand", "LeftUpperLeg", "RightUpperLeg", "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot"}
    missing = sorted(required - set(mapping))
    if missing:
        raise KeyError(f"skeleton {rig.skeleton.name!r}: no joint found for the Unity humanoid bones {', '.join(missing)}")
    return mapping
