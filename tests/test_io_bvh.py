"""BVH reader: hierarchy, forward kinematics, units, malformed files."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from streamfix.io.bvh import CMU_SCALE, read_bvh
from streamfix.io.errors import MotionFileError
from streamfix.skeletons import get_skeleton

CMU = {"131_01.bvh": 994, "131_02.bvh": 1247}
XIA = {
    "angry_13_000.bvh": 140,
    "depressed_13_000.bvh": 189,
    "depressed_18_000.bvh": 105,
    "neutral_01_000.bvh": 327,
    "neutral_16_000.bvh": 150,
    "old_13_000.bvh": 189,
}
ALL = [("cmu_bvh", n, f) for n, f in CMU.items()] + [("xia_bvh", n, f) for n, f in XIA.items()]


@pytest.mark.parametrize("folder,name,frames", ALL)
def test_reads_real_takes(shared_data, folder, name, frames):
    m = read_bvh(shared_data / folder / name)
    assert m.n_frames == frames
    assert m.n_joints == 31  # 31 joints, End Sites excluded
    assert m.rate_hz == 120.0
    assert m.meta["scale"] == CMU_SCALE  # chosen by the documented unit rule
    assert get_skeleton(m.skeleton.name) == m.skeleton  # registered
    assert m.skeleton.n_bones == 30
    assert np.isfinite(m.positions).all() and m.observed.all()
    # bone lengths constant over time and equal to the OFFSET norms x scale
    b = m.skeleton.bone_array
    L = np.linalg.norm(m.positions[:, b[:, 0]] - m.positions[:, b[:, 1]], axis=2)
    np.testing.assert_allclose(L, np.broadcast_to(m.meta["bone_lengths"], L.shape), atol=1e-9)
    # metres: a human-size skeleton, y up (head above feet)
    hips = m.skeleton.index("Hips")
    head = m.skeleton.index("Head")
    assert 0.3 < np.median(m.positions[:, head, 1] - m.positions[:, hips, 1]) < 0.9
    thigh = np.median(L[:, [i for i, (p, c) in enumerate(m.skeleton.bones) if m.skeleton.joint_names[c] in ("LeftKnee", "LeftLeg")][0]])
    assert 0.3 < thigh < 0.55  # a thigh is ~0.4 m


def test_cmu_walk_moves_and_feet_touch_a_floor(shared_data):
    m = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh")
    hips = m.positions[:, m.skeleton.index("Hips")]
    assert np.linalg.norm(hips[-1, [0, 2]] - hips[0, [0, 2]]) > 1.0  # start, walk, stop
    toes = m.positions[:, [m.skeleton.index("LeftToe"), m.skeleton.index("RightToe")], 1]
    floor = toes.min(axis=1)
    # the lower toe stays at one floor height while walking (FK errors would make it wander)
    assert np.percentile(floor, 95) - np.percentile(floor, 5) < 0.08


def _bvh(channels_root="Xposition Yposition Zposition Zrotation Yrotation Xrotation", chan_child="Zrotation Xrotation Yrotation", motion="", frames=1, offset_child="0 1 0"):
    nr = len(channels_root.split())
    nc = len(chan_child.split())
    return f"""HIERARCHY
ROOT Root
{{
  OFFSET 0 0 0
  CHANNELS {nr} {channels_root}
  JOINT Child
  {{
    OFFSET {offset_child}
    CHANNELS {nc} {chan_child}
    End Site
    {{
      OFFSET 2 0 0
    }}
  }}
}}
MOTION
Frames: {frames}
Frame Time: 0.0333333
{motion}
"""


def test_known_pose_against_scipy_euler(tmp_path):
    rng = np.random.default_rng(1)
    T = 5
    root_t = rng.uniform(-3, 3, size=(T, 3))
    root_zyx = rng.uniform(-180, 180, size=(T, 3))
    child_zxy = rng.uniform(-180, 180, size=(T, 3))
    rows = np.concatenate([root_t, root_zyx, child_zxy], axis=1)
    text = _bvh(motion="\n".join(" ".join(f"{v:.10f}" for v in r) for r in rows), frames=T)
    p = tmp_path / "pose.bvh"
    p.write_text(text)
    m = read_bvh(p, scale=1.0, include_end_sites=True)
    assert m.skeleton.joint_names == ("Root", "Child", "Child_End")
    assert m.rate_hz == 30.0
    Rr = Rotation.from_euler("ZYX", root_zyx, degrees=True)  # intrinsic, composed in listed order
    Rc = Rotation.from_euler("ZXY", child_zxy, degrees=True)
    child = root_t + Rr.apply([0.0, 1.0, 0.0])
    end = child + (Rr * Rc).apply([2.0, 0.0, 0.0])
    np.testing.assert_allclose(m.positions[:, 0], root_t, atol=1e-9)
    np.testing.assert_allclose(m.positions[:, 1], child, atol=1e-9)
    np.testing.assert_allclose(m.positions[:, 2], end, atol=1e-9)


def test_position_channels_in_any_order(tmp_path):
    # rotation listed before positions, positions permuted: translation must still be (1, 2, 3)
    text = _bvh(
        channels_root="Zrotation Zposition Xposition Yposition",
        chan_child="Xrotation",
        motion="90 3 1 2 0",
    )
    p = tmp_path / "order.bvh"
    p.write_text(text)
    m = read_bvh(p, scale=1.0)
    np.testing.assert_allclose(m.positions[0, 0], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(m.positions[0, 1], [0, 2, 3], atol=1e-12)  # Rz(90) (0,1,0) = (-1,0,0)


def test_explicit_scale(shared_data):
    a = read_bvh(shared_data / "xia_bvh" / "angry_13_000.bvh")
    b = read_bvh(shared_data / "xia_bvh" / "angry_13_000.bvh", scale=1.0)
    np.testing.assert_allclose(a.positions, b.positions * CMU_SCALE)


@pytest.mark.parametrize(
    "mutate,pattern",
    [
        (lambda t: t.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Wrotation Yrotation"),
         r"bad\.bvh line 9: bad CHANNELS for 'Child': 'Wrotation'"),
        (lambda t: t.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS x Zrotation"),
         r"line 9: CHANNELS count of 'Child' is not an integer: 'x'"),
        (lambda t: t.replace("Frames: 3", "Frames: 5"),
         r"truncated MOTION block: 'Frames: 5' declared, 3 frame lines found"),
        (lambda t: t.replace("0 0 0 0 0 0 1 2 3\n", "0 0 0 0 0 0 1 2\n", 1),
         r"line 19: frame 0: expected 9 channel values .*got 8"),
        (lambda t: t.replace("0 0 0 0 0 0 4 5 6", "0 0 0 0 0 0 4 five 6"),
         r"line 20: channel value 7 is not a number: 'five'"),
        (lambda t: t.replace("OFFSET 0 1 0", "OFFSET 0 1"),
         r"line 9: OFFSET z of 'Child' is not a number: 'CHANNELS'"),
        (lambda t: t.split("MOTION")[0],
         r"unexpected end of file in HIERARCHY"),
        (lambda t: t.replace("Frame Time: 0.0333333", "Frame Time: 0"),
         r"line 18: Frame Time must be positive"),
        # a hierarchy with no motion is refused when read, naming why (the writer's "root joint is
        # missing in every frame" was all `streamfix clean` said of it)
        (lambda t: t.replace("Frames: 3", "Frames: 0").split("Frame Time: 0.0333333")[0] + "Frame Time: 0.0333333\n",
         r"bad\.bvh line 17: no frames \('Frames: 0'\)"),
    ],
)
def test_malformed(tmp_path, mutate, pattern):
    motion = "0 0 0 0 0 0 1 2 3\n0 0 0 0 0 0 4 5 6\n0 0 0 0 0 0 7 8 9"
    text = mutate(_bvh(motion=motion, frames=3))
    p = tmp_path / "bad.bvh"
    p.write_text(text)
    with pytest.raises(MotionFileError, match=pattern):
        read_bvh(p, scale=1.0)
