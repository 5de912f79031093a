"""BVH -> Kinect v2 retargeting, checked against the real Kinect v2 recordings."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.io.bvh import read_bvh
from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.io.retarget import bvh_to_kinect_v2
from streamfix.skeletons import KINECT_V2 as K

TAKES = ["cmu_bvh/131_01.bvh", "cmu_bvh/131_02.bvh", "xia_bvh/angry_13_000.bvh", "xia_bvh/neutral_01_000.bvh",
         "xia_bvh/old_13_000.bvh"]


def _median_lengths(m):
    b = K.bone_array
    ok = (m.confidence[:, b[:, 0]] == 1) & (m.confidence[:, b[:, 1]] == 1)
    L = np.linalg.norm(m.positions[:, b[:, 0]] - m.positions[:, b[:, 1]], axis=2)
    L[~ok] = np.nan
    return np.nanmedian(L, axis=0)


@pytest.fixture(scope="module")
def kinect_reference(shared_data):
    files = sorted((shared_data / "kinect_v2").glob("Ges0*.csv"))
    return [read_kinect_csv(f) for f in files]


@pytest.mark.parametrize("take", TAKES)
def test_retarget_is_anatomically_kinect_like(shared_data, kinect_reference, take):
    src = read_bvh(shared_data / take)
    m = bvh_to_kinect_v2(src, to_camera=True)
    assert m.skeleton is K and m.n_frames == src.n_frames and m.rate_hz == src.rate_hz
    assert np.isfinite(m.positions).all() and m.observed.all()
    # bone lengths within a plausible factor of a real Kinect v2 subject's (same bones)
    ref = np.median([_median_lengths(r) for r in kinect_reference], axis=0)
    ratio = _median_lengths(m) / ref
    major = [i for i, (p, c) in enumerate(K.bones) if K.joint_names[c] in
             ("SpineMid", "SpineShoulder", "ShoulderLeft", "ElbowLeft", "WristLeft", "ShoulderRight", "ElbowRight",
              "WristRight", "KneeLeft", "AnkleLeft", "KneeRight", "AnkleRight", "HipLeft", "HipRight", "Head")]
    assert np.all((ratio[major] > 0.45) & (ratio[major] < 1.6)), dict(zip(np.array(K.joint_names)[K.bone_array[major, 1]], ratio[major].round(2)))
    # vertical order of the spine, as in every standing Kinect recording
    y = np.median(m.positions[..., 1], axis=0)
    order = [K.index(n) for n in ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head")]
    assert np.all(np.diff(y[order]) > 0)
    assert y[K.index("KneeLeft")] < y[K.index("HipLeft")] and y[K.index("AnkleRight")] < y[K.index("KneeRight")]


def test_camera_frame_matches_the_sensor_convention(shared_data, kinect_reference):
    """Left/right and facing direction agree with how a real Kinect v2 labels a subject facing it."""
    m = bvh_to_kinect_v2(read_bvh(shared_data / "cmu_bvh" / "131_01.bvh"), to_camera=True)
    dx = lambda mm, a, b: np.nanmedian(mm.positions[:, K.index(a), 0] - mm.positions[:, K.index(b), 0])
    dz = lambda mm, a, b: np.nanmedian(mm.positions[:, K.index(a), 2] - mm.positions[:, K.index(b), 2])
    for r in kinect_reference:
        assert np.sign(dx(m, "ShoulderLeft", "ShoulderRight")) == np.sign(dx(r, "ShoulderLeft", "ShoulderRight"))
        assert np.sign(dx(m, "HipLeft", "HipRight")) == np.sign(dx(r, "HipLeft", "HipRight"))
        # toes point at the sensor: the foot is nearer the camera than the ankle
        assert dz(r, "FootLeft", "AnkleLeft") < 0
    assert dz(m, "FootLeft", "AnkleLeft") < 0 and dz(m, "FootRight", "AnkleRight") < 0
    np.testing.assert_allclose(m.positions[0, K.index("SpineBase")], [0, -0.35, 2.7])


def test_end_sites_used_when_present(shared_data):
    plain = bvh_to_kinect_v2(read_bvh(shared_data / "cmu_bvh" / "131_01.bvh"))
    ends = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh", include_end_sites=True)
    withend = bvh_to_kinect_v2(ends)
    tip = K.index("HandTipLeft")
    np.testing.assert_allclose(withend.positions[:, tip], ends.positions[:, ends.skeleton.index("LFingers_End")])
    same = [K.index(n) for n in ("ElbowLeft", "KneeRight", "SpineMid")]
    np.testing.assert_allclose(withend.positions[:, same], plain.positions[:, same])


def test_unknown_skeleton_names_what_is_missing(shared_data):
    m = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh")
    kin = bvh_to_kinect_v2(m)
    with pytest.raises(ValueError, match="no joint for SpineBase"):
        bvh_to_kinect_v2(kin)


def test_reproportion_to_kinect_lengths(shared_data, kinect_reference):
    src = read_bvh(shared_data / "xia_bvh" / "old_13_000.bvh")
    target = np.median([_median_lengths(r) for r in kinect_reference], axis=0)
    plain = bvh_to_kinect_v2(src)
    m = bvh_to_kinect_v2(src, bone_lengths=target)
    b = K.bone_array
    L = np.linalg.norm(m.positions[:, b[:, 0]] - m.positions[:, b[:, 1]], axis=2)
    np.testing.assert_allclose(L, np.broadcast_to(target, L.shape), atol=1e-9)
    d = lambda x: (x[:, b[:, 1]] - x[:, b[:, 0]]) / np.linalg.norm(x[:, b[:, 1]] - x[:, b[:, 0]], axis=2, keepdims=True)
    np.testing.assert_allclose(d(m.positions), d(plain.positions), atol=1e-9)
    np.testing.assert_array_equal(m.positions[:, 0], plain.positions[:, 0])
    with pytest.raises(ValueError, match=r"bone_lengths must be \(24,\)"):
        bvh_to_kinect_v2(src, bone_lengths=target[:5])
