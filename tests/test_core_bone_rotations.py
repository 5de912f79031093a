"""Positions -> local rotations -> forward kinematics, on real takes and against the BVH reader's FK."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from streamfix.core.bone_rotations import (
    forward_kinematics,
    local_positions,
    parent_array,
    solve_local_rotations,
    topological_order,
)
from streamfix.humanoid import build_rig, median_bone_lengths, t_pose_directions
from streamfix.io import read_motion
from streamfix.io.bvh import bvh_forward_kinematics, parse_bvh_hierarchy
from streamfix.skeletons import AZURE_KINECT, COCO_17, KINECT_V1_UIPRMD, KINECT_V2


def _bvh_tree(path):
    nodes, _ = parse_bvh_hierarchy(path, path.read_text().splitlines())
    keep = [i for i, n in enumerate(nodes) if not n.end_site]
    remap = {old: new for new, old in enumerate(keep)}
    parents = np.array([remap.get(nodes[k].parent, -1) for k in keep])
    return nodes, keep, parents, np.array([nodes[k].offset for k in keep])


@pytest.mark.parametrize("take", ["cmu_bvh/131_02.bvh", "xia_bvh/old_13_000.bvh"])
def test_real_bvh_positions_round_trip_exactly(shared_data, take):
    m = read_motion(shared_data / take)
    _, _, parents, offsets = _bvh_tree(shared_data / take)
    q = solve_local_rotations(m.positions, parents, offsets * m.meta["scale"])
    assert q.shape == (m.n_frames, m.n_joints, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=2), 1.0, atol=1e-12)
    X = forward_kinematics(m.positions[:, 0], q, parents, offsets * m.meta["scale"])
    assert np.abs(X - m.positions).max() < 1e-3  # 1 mm: the bone lengths are exact


def test_random_rotations_reproduced_and_match_the_bvh_reader(shared_data):
    # an independent FK (the BVH reader's Euler channels) makes the positions; the solve must rebuild them
    path = shared_data / "xia_bvh" / "neutral_16_000.bvh"
    nodes, keep, parents, offsets = _bvh_tree(path)
    rng = np.random.default_rng(7)
    n_channels = sum(len(n.channels) for n in nodes)
    values = rng.uniform(-120, 120, size=(20, n_channels))
    X = bvh_forward_kinematics(nodes, values)[:, keep]
    q = solve_local_rotations(X, parents, offsets)
    np.testing.assert_allclose(forward_kinematics(X[:, 0], q, parents, offsets), X, atol=1e-9)


def test_kinect_layout_rig_exact_when_lengths_are_and_bounded_when_not(shared_data):
    m = read_motion(shared_data / "kinect_v2" / "Ges03_drawlines.csv")
    sk = m.skeleton
    parents = parent_array(sk.bone_array, sk.n_joints)
    lengths = median_bone_lengths(m.positions, sk)
    # the same directions with each bone at its median length: exact lengths
    P = np.nan_to_num(m.positions)
    exact = P.copy()
    child_len = np.zeros(sk.n_joints)
    child_len[sk.bone_array[:, 1]] = lengths
    for j in topological_order(parents):
        p = parents[j]
        if p >= 0:
            d = P[:, j] - P[:, p]
            exact[:, j] = exact[:, p] + d / np.linalg.norm(d, axis=1, keepdims=True) * child_len[j]
    rig = build_rig(sk, lengths)
    for data, tolerance in ((exact, 1e-3), (P, None)):
        X = rig.node_positions(data)
        q = solve_local_rotations(X, rig.parents, rig.offsets, rig.primary)
        back = forward_kinematics(X[:, 0], q, rig.parents, rig.offsets)
        err = np.linalg.norm(back - X, axis=2)
        if tolerance is not None:
            assert err.max() < tolerance
        else:  # raw sensor: every bone aimed exactly, so the error is at most the summed length changes above it
            dev = np.zeros_like(err)
            seg = np.abs(np.linalg.norm(X - X[:, np.maximum(rig.parents, 0)], axis=2) - np.linalg.norm(rig.offsets, axis=1))
            for k in topological_order(rig.parents):
                if rig.parents[k] >= 0:
                    dev[:, k] = dev[:, rig.parents[k]] + seg[:, k]
            assert (err <= dev + 1e-6).all() and err.max() > 1e-3
        # per-frame offsets make any pose exact
        exact_back = forward_kinematics(X[:, 0], q, rig.parents, rig.offsets, local_positions(X, q, rig.parents))
        assert np.abs(exact_back - X).max() < 1e-9


def test_twist_comes_from_the_hips_and_a_reversed_bone_is_reached():
    # root with a spine up and two hips sideways; turn the body 90 deg about y and flip the spine down
    parents = np.array([-1, 0, 0, 0])
    offsets = np.array([[0, 0, 0], [0, 1.0, 0], [0.2, 0, 0], [-0.2, 0, 0]])
    turn = Rotation.from_euler("y", 90, degrees=True)
    pose = np.array([[0, 0, 0], [0, 1.0, 0], [0.2, 0, 0], [-0.2, 0, 0]])
    frames = np.stack([pose, turn.apply(pose), pose * [1, -1, 1]])
    q = solve_local_rotations(frames, parents, offsets)
    back = forward_kinematics(frames[:, 0], q, parents, offsets)
    np.testing.assert_allclose(back[:2], frames[:2], atol=1e-12)
    assert Rotation.from_quat(q[1, 0]).approx_equal(turn, atol=1e-9)  # the twist is the hips' turn
    np.testing.assert_allclose(back[2, 1], [0, -1, 0], atol=1e-12)  # 180 deg swing


def test_a_target_along_the_primary_bone_at_rest_does_not_twist_it():
    # a wrist with its hand and thumb both along +x at rest (a T-pose): the thumb's offset
    # has no part perpendicular to the hand's, so it cannot tell the twist (its angle was
    # round-off against the thumb's jitter: up to 180 degrees). The hand swings up to 40
    # degrees, the thumb stays near the hand's line with 2 mm of jitter: the wrist turns
    # by the swing only
    parents = np.array([-1, 0, 0])
    offsets = np.array([[0, 0, 0], [0.06, 0, 0], [0.07, 0, 0]])
    rng = np.random.default_rng(0)
    angle = np.radians(np.linspace(0, 40, 50))
    hand = np.stack([np.cos(angle), np.sin(angle), np.zeros(50)], axis=1)
    thumb = 0.07 * hand + rng.normal(0, 0.002, (50, 3))
    frames = np.stack([np.zeros((50, 3)), 0.06 * hand, thumb], axis=1)
    q = solve_local_rotations(frames, parents, offsets)
    np.testing.assert_allclose(Rotation.from_quat(q[:, 0]).magnitude(), angle, atol=1e-9)
    np.testing.assert_allclose(forward_kinematics(frames[:, 0], q, parents, offsets)[:, 1], frames[:, 1], atol=1e-12)


def test_missing_joint_keeps_parent_rotation_without_spreading_nan():
    parents = np.array([-1, 0, 1])
    offsets = np.array([[0, 0, 0], [0, 1.0, 0], [0, 1.0, 0]])
    frame = np.array([[[0, 0, 0], [1.0, 0, 0], [np.nan, np.nan, np.nan]]])
    q = solve_local_rotations(frame, parents, offsets)
    assert np.isfinite(q).all()
    np.testing.assert_allclose(q[0, 2], [0, 0, 0, 1], atol=1e-12)


def test_bad_trees_are_named():
    with pytest.raises(ValueError, match="two parents"):
        parent_array(np.array([[0, 1], [2, 1]]), 3)
    with pytest.raises(ValueError, match="graph|not a tree|two parents|no parent"):
        parent_array(COCO_17.bone_array, COCO_17.n_joints)


@pytest.mark.parametrize("skeleton", [KINECT_V2, AZURE_KINECT, KINECT_V1_UIPRMD])
def test_t_pose_limbs_point_where_a_t_pose_puts_them(skeleton):
    d = t_pose_directions(skeleton)
    idx = skeleton.index
    names = {KINECT_V2.name: ("ElbowLeft", "KneeRight", "Head", "FootLeft"),
             AZURE_KINECT.name: ("ELBOW_LEFT", "KNEE_RIGHT", "HEAD", "FOOT_LEFT"),
             KINECT_V1_UIPRMD.name: ("LElbow", "RKnee", "Head", "LFoot")}[skeleton.name]
    np.testing.assert_allclose(d[idx(names[0])], [1, 0, 0])  # left arm out to +x (the body's left)
    np.testing.assert_allclose(d[idx(names[1])], [0, -1, 0])  # shin down
    np.testing.assert_allclose(d[idx(names[2])], [0, 1, 0])  # head up
    np.testing.assert_allclose(d[idx(names[3])], [0, 0, 1])  # foot forward
