"""VMC output received by a real python-osc server on loopback; joints rebuilt from the packets."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pythonosc", reason="VMC output needs python-osc (the 'outputs' extra)")
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer
from scipy.spatial.transform import Rotation

from streamfix.io import read_motion
from streamfix.transport.vmc import VmcSender, parse_host_port

# Unity's humanoid hierarchy, as a receiver knows it (not taken from streamfix)
UNITY_PARENT = {
    "Spine": "Hips", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
    "LeftShoulder": "Chest", "LeftUpperArm": "LeftShoulder", "LeftLowerArm": "LeftUpperArm", "LeftHand": "LeftLowerArm",
    "RightShoulder": "Chest", "RightUpperArm": "RightShoulder", "RightLowerArm": "RightUpperArm",
    "RightHand": "RightLowerArm",
    "LeftUpperLeg": "Hips", "LeftLowerLeg": "LeftUpperLeg", "LeftFoot": "LeftLowerLeg", "LeftToes": "LeftFoot",
    "RightUpperLeg": "Hips", "RightLowerLeg": "RightUpperLeg", "RightFoot": "RightLowerLeg", "RightToes": "RightFoot",
}
# Unity T-pose direction of the bone ending at each bone (left-handed: the avatar's left is -x)
UNITY_REST = {"LeftLowerArm": (-1, 0, 0), "LeftHand": (-1, 0, 0), "RightLowerArm": (1, 0, 0), "RightHand": (1, 0, 0),
              "LeftLowerLeg": (0, -1, 0), "LeftFoot": (0, -1, 0), "RightLowerLeg": (0, -1, 0), "RightFoot": (0, -1, 0),
              "Neck": (0, 1, 0), "Head": (0, 1, 0)}
# the skeleton joint each Unity bone sits at, per layout
KINECT_JOINT = {"Hips": "SpineBase", "Spine": "SpineMid", "Chest": "SpineShoulder", "Neck": "Neck", "Head": "Head",
                "LeftShoulder": "SpineShoulder", "LeftUpperArm": "ShoulderLeft", "LeftLowerArm": "ElbowLeft",
                "LeftHand": "WristLeft", "RightShoulder": "SpineShoulder", "RightUpperArm": "ShoulderRight",
                "RightLowerArm": "ElbowRight", "RightHand": "WristRight", "LeftUpperLeg": "HipLeft",
                "LeftLowerLeg": "KneeLeft", "LeftFoot": "AnkleLeft", "LeftToes": "FootLeft", "RightUpperLeg": "HipRight",
                "RightLowerLeg": "KneeRight", "RightFoot": "AnkleRight", "RightToes": "FootRight"}
CMU_JOINT = {"Hips": "Hips", "Spine": "Chest", "Chest": "Chest2", "Neck": "Neck", "Head": "Head",
             "LeftShoulder": "LeftCollar", "LeftUpperArm": "LeftShoulder", "LeftLowerArm": "LeftElbow",
             "LeftHand": "LeftWrist", "RightShoulder": "RightCollar", "RightUpperArm": "RightShoulder",
             "RightLowerArm": "RightElbow", "RightHand": "RightWrist", "LeftUpperLeg": "LeftHip",
             "LeftLowerLeg": "LeftKnee", "LeftFoot": "LeftAnkle", "LeftToes": "LeftToe", "RightUpperLeg": "RightHip",
             "RightLowerLeg": "RightKnee", "RightFoot": "RightAnkle", "RightToes": "RightToe"}


def _receive(n_frames: int, send) -> list[dict]:
    """Start a real OSC server on an ephemeral loopback port, call ``send(port)``, decode ``n_frames`` bundles."""
    frames: list[dict] = []

    def on_message(address, *args):
        if address == "/VMC/Ext/OK":
            frames.append({"ok": args, "bones": {}})
        elif address == "/VMC/Ext/T":
            frames[-1]["t"] = args[0]
        elif address == "/VMC/Ext/Root/Pos":
            frames[-1]["root"] = args
        elif address == "/VMC/Ext/Bone/Pos":
            frames[-1]["bones"][args[0]] = np.array(args[1:], dtype=np.float64)

    dispatcher = Dispatcher()
    dispatcher.set_default_handler(on_message)
    server = BlockingOSCUDPServer(("127.0.0.1", 0), dispatcher)
    server.timeout = 2.0
    try:
        send(server.server_address[1])
        for _ in range(n_frames):
            server.handle_request()
    finally:
        server.server_close()
    return frames


def _rebuild(bones: dict[str, np.ndarray]) -> tuple[dict, dict]:
    """Global positions and rotations (right-handed, metres) of the received bones by Unity's hierarchy."""
    pos, rot = {}, {}
    for name in ["Hips"] + list(UNITY_PARENT):
        if name not in bones:
            continue
        p = bones[name][:3] * [-1, 1, 1]  # Unity -> right-handed: mirror x
        q = bones[name][3:] * [1, -1, -1, 1]
        R = Rotation.from_quat(q).as_matrix()
        parent = UNITY_PARENT.get(name)
        if parent is None:
            pos[name], rot[name] = p, R
        else:
            pos[name] = pos[parent] + rot[parent] @ p
            rot[name] = rot[parent] @ R
    return pos, rot


@pytest.mark.parametrize("path,joints", [("kinect_v2/Ges01_wavehand.csv", KINECT_JOINT), ("cmu_bvh/131_01.bvh", CMU_JOINT)])
def test_vmc_packets_rebuild_the_joints(shared_data, path, joints):
    motion = read_motion(shared_data / path)
    n = 40
    positions = motion.positions[:n]
    sender_frames = []

    def send(port):
        with VmcSender(motion.skeleton, port=port) as sender:
            for t in range(n):
                sender_frames.append(sender.send(positions[t], motion.timestamps[t]))

    frames = _receive(n, send)
    assert all(sender_frames) and len(frames) == n
    worst = 0.0
    for t, frame in enumerate(frames):
        assert frame["ok"][0] == 1 and frame["t"] == pytest.approx(motion.timestamps[t] - motion.timestamps[0], abs=1e-4)
        assert frame["root"][0] == "root"
        assert set(frame["bones"]) == set(joints)  # every humanoid bone of the layout, Unity names
        pos, rot = _rebuild(frame["bones"])
        for bone, joint in joints.items():
            err = np.linalg.norm(pos[bone] - positions[t, motion.skeleton.index(joint)])
            worst = max(worst, err)
        # rotations alone place the limbs: the parent's rotation turns the Unity T-pose
        # direction onto the measured bone (what an avatar that keeps its own proportions shows)
        for bone, rest in UNITY_REST.items():
            parent = UNITY_PARENT[bone]
            d = positions[t, motion.skeleton.index(joints[bone])] - positions[t, motion.skeleton.index(joints[parent])]
            rest_rh = np.array(rest, float) * [-1, 1, 1]
            assert np.linalg.norm(rot[parent] @ rest_rh * np.linalg.norm(d) - d) < 0.01, (t, bone)
    assert worst < 0.01  # within 1 cm (float32 on the wire)


def test_vmc_target_parsing():
    assert parse_host_port("39540") == ("127.0.0.1", 39540)
    assert parse_host_port("192.168.1.5:39539") == ("192.168.1.5", 39539)
    assert parse_host_port("") == ("127.0.0.1", 39539)
    with pytest.raises(ValueError, match="not a number"):
        parse_host_port("host:abc")
    with pytest.raises(ValueError, match="outside"):
        parse_host_port("70000")


def test_layouts_without_a_humanoid_are_refused_by_name():
    from streamfix.skeletons import COCO_17, MEDIAPIPE_POSE

    for skeleton in (COCO_17, MEDIAPIPE_POSE):
        with pytest.raises((KeyError, ValueError), match="tree|parent"):
            VmcSender(skeleton, port=9)


def test_missing_joints_go_out_at_their_rest_offset(shared_data):
    from streamfix.transport.vmc import VmcBones

    motion = read_motion(shared_data / "kinect_v2" / "Ges02_balancinghands.csv")
    frames = motion.positions[:5].copy()
    elbow = motion.skeleton.index("ElbowLeft")
    frames[:, elbow] = np.nan  # never seen: the sender still starts, with a 1 m placeholder bone
    bones = VmcBones.for_positions(motion.skeleton, frames)
    pos, rot = bones.transforms(frames)
    assert np.isfinite(pos).all() and np.isfinite(rot).all()
    i = bones.bones.index("LeftLowerArm")
    np.testing.assert_allclose(pos[:, i], np.broadcast_to(bones.rest_offsets[i], pos[:, i].shape))
    assert bones.rest_offsets[i][0] > 0  # the T-pose upper arm points out to the body's left (+x)
    j = bones.bones.index("RightLowerArm")  # a present joint is sent where it was measured
    assert not np.allclose(pos[:, j], bones.rest_offsets[j])


def test_kinect_hands_turn_as_little_as_the_forearms_that_carry_them(shared_data):
    # the Kinect v2 wrist aims at the hand and the thumb, both along the arm in the T-pose:
    # their twist was noise, and received hands spun by up to 180 degrees every frame
    from streamfix.cleaning import clean_recording
    from streamfix.transport.vmc import VmcBones

    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    positions = clean_recording(m).motion.positions
    bones = VmcBones.for_positions(m.skeleton, positions)
    q = bones.transforms(positions)[1]
    for side in ("Left", "Right"):
        hand = Rotation.from_quat(q[:, bones.bones.index(f"{side}Hand")])
        arm = Rotation.from_quat(q[:, bones.bones.index(f"{side}LowerArm")])
        hand_step = np.degrees((hand[1:] * hand[:-1].inv()).magnitude())
        arm_step = np.degrees((arm[1:] * arm[:-1].inv()).magnitude())
        assert np.percentile(hand_step, 95) < 3 * np.percentile(arm_step, 95) + 2.0, side

