"""Data model: skeleton registry and Motion invariants."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.motion import CONFIDENCE_INFERRED, Motion
from streamfix.skeletons import (
    AZURE_KINECT,
    KINECT_V2,
    MEDIAPIPE_POSE,
    Skeleton,
    get_skeleton,
    register_skeleton,
)


def _is_tree(skeleton: Skeleton) -> bool:
    """Connected with J-1 edges and every joint reachable from joint 0."""
    if skeleton.n_bones != skeleton.n_joints - 1:
        return False
    adjacency = {i: set() for i in range(skeleton.n_joints)}
    for a, b in skeleton.bones:
        adjacency[a].add(b)
        adjacency[b].add(a)
    seen, todo = {0}, [0]
    while todo:
        for n in adjacency[todo.pop()] - seen:
            seen.add(n)
            todo.append(n)
    return len(seen) == skeleton.n_joints


def test_builtin_skeleton_sizes():
    assert (KINECT_V2.n_joints, KINECT_V2.n_bones) == (25, 24)
    assert AZURE_KINECT.n_joints == 32
    assert MEDIAPIPE_POSE.n_joints == 33
    assert _is_tree(KINECT_V2) and _is_tree(AZURE_KINECT)


def test_kinect_v2_order_matches_sdk_jointtype():
    # JointType enum values of the Kinect for Windows SDK 2.0
    assert KINECT_V2.index("SpineBase") == 0
    assert KINECT_V2.index("SpineShoulder") == 20
    assert KINECT_V2.index("ThumbRight") == 24
    assert (KINECT_V2.index("ElbowLeft"), KINECT_V2.index("WristLeft")) in KINECT_V2.bones


def test_unknown_skeleton_error_lists_known_names():
    with pytest.raises(KeyError, match="kinect_v2"):
        get_skeleton("no_such_sensor")


def test_register_refuses_silent_replacement():
    custom = Skeleton("test_custom", ("a", "b"), ((0, 1),))
    register_skeleton(custom)
    assert get_skeleton("test_custom") is custom
    with pytest.raises(ValueError):
        register_skeleton(Skeleton("test_custom", ("a", "b", "c"), ((0, 1), (1, 2))))


def test_bad_bone_rejected():
    with pytest.raises(ValueError, match="does not join"):
        Skeleton("bad", ("a", "b"), ((0, 2),))


def test_a_cycle_of_parent_links_is_refused_by_name_but_a_joint_may_have_two_parents():
    # a directed cycle has no root: the engine failed on it only at its first window
    with pytest.raises(ValueError, match=r"form a cycle \(b -> c -> a -> b\)"):
        Skeleton("loop", ("a", "b", "c"), ((0, 1), (1, 2), (2, 0)))
    with pytest.raises(ValueError, match="cycle"):
        Skeleton("tail", ("r", "a", "b", "c"), ((0, 1), (1, 2), (2, 3), (3, 1)))
    assert Skeleton("diamond", ("a", "b", "c", "d"), ((0, 1), (0, 2), (1, 3), (2, 3))).n_bones == 4


def test_skeleton_dict_round_trip():
    assert Skeleton.from_dict(KINECT_V2.to_dict()) == KINECT_V2


def test_motion_treats_nan_as_missing_and_keeps_the_rest():
    positions = np.random.default_rng(0).normal(size=(4, 25, 3))
    positions[1, 3, 2] = np.nan
    positions[2, 5, 0] = np.inf
    confidence = np.ones((4, 25))
    confidence[3, 7] = CONFIDENCE_INFERRED
    motion = Motion(positions, confidence, np.arange(4) / 30.0, 30.0, KINECT_V2)
    assert not motion.observed[1, 3] and not motion.observed[2, 5]
    assert np.isnan(motion.positions[1, 3]).all()
    assert motion.observed.sum() == 4 * 25 - 2
    assert motion.confidence[3, 7] == CONFIDENCE_INFERRED


def test_motion_wrong_joint_count_names_expected_count():
    with pytest.raises(ValueError, match="expects 25 joints"):
        Motion(np.zeros((2, 24, 3)), np.ones((2, 24)), np.arange(2.0), 30.0, KINECT_V2)


def test_slice_and_copy_are_independent():
    motion = Motion.from_positions(np.zeros((10, 25, 3)), KINECT_V2, 30.0)
    part = motion.slice(2, 5)
    part.positions[:] = 1.0
    assert part.n_frames == 3 and motion.positions.max() == 0.0
    assert part.timestamps[0] == pytest.approx(2 / 30.0)
