"""Normalisation and augmentation geometry of the prior (numpy only, no model needed)."""
from __future__ import annotations

import numpy as np

from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.prior.data import cut_windows, resample_masked
from streamfix.prior.normalize import (
    KINECT_V2_LIMBS,
    KINECT_V2_MIRROR,
    apply_norm,
    denormalise,
    facing_angle,
    normalise,
    rot_y,
)
from streamfix.skeletons import KINECT_V2


def _kinect(shared_data):
    m = read_kinect_csv(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    return m.positions[:64], m.confidence[:64] >= 1.0


def test_mirror_swaps_left_and_right_names():
    names = KINECT_V2.joint_names
    assert np.array_equal(KINECT_V2_MIRROR[KINECT_V2_MIRROR], np.arange(25))  # an involution
    for j, k in enumerate(KINECT_V2_MIRROR):
        expected = names[j].replace("Left", "#").replace("Right", "Left").replace("#", "Right")
        assert names[k] == expected
    # mirrored bones are bones: the swap respects the skeleton
    bones = {tuple(b) for b in KINECT_V2.bone_array.tolist()}
    assert {(int(KINECT_V2_MIRROR[a]), int(KINECT_V2_MIRROR[b])) for a, b in bones} == bones


def test_limbs_are_the_papers_sizes():
    assert [len(KINECT_V2_LIMBS[k]) for k in ("right_arm", "left_arm", "right_leg", "left_leg")] == [6, 6, 4, 4]
    names = KINECT_V2.joint_names
    assert all("Right" in names[j] for j in KINECT_V2_LIMBS["right_arm"] + KINECT_V2_LIMBS["right_leg"])


def test_normalise_round_trip_and_invariances(shared_data):
    pos, obs = _kinect(shared_data)
    bones = KINECT_V2.bone_array
    ref = np.full(len(bones), 0.2)
    template = np.nan_to_num(np.nanmean(pos - pos[:, :1], axis=0))
    y, norm = normalise(pos, obs, bones, ref, template=template)
    assert np.all(y[~obs] == 0)
    back = denormalise(y, norm)
    np.testing.assert_allclose(back[obs], pos[obs], atol=1e-9)
    np.testing.assert_allclose(apply_norm(np.nan_to_num(pos), norm)[obs], y[obs], atol=1e-12)
    # a body turned by 40 deg, moved and 20 % larger normalises to the same window
    moved = (pos - pos[:, :1]) @ rot_y(0.7).T * 1.2 + np.array([1.0, 0.2, -3.0])
    y2, norm2 = normalise(moved, obs, bones, ref, template=template)
    np.testing.assert_allclose(y2[obs], y[obs], atol=1e-6)
    assert abs(norm2.scale / norm.scale - 1.2) < 1e-9


def test_facing_angle_recovers_a_known_turn():
    rng = np.random.default_rng(0)
    template = rng.normal(0, 0.3, (25, 3))
    for theta in (-2.5, -0.3, 0.0, 1.0, 3.0):
        pose = np.repeat(template[None], 4, axis=0) @ rot_y(-theta).T
        obs = rng.random((4, 25)) > 0.5  # any subset of joints determines it
        est = facing_angle(pose, obs, template)
        assert abs(np.angle(np.exp(1j * (est - theta)))) < 1e-9


def test_resample_and_windows_cover_every_frame(shared_data):
    pos, obs = _kinect(shared_data)
    r, m = resample_masked(pos, obs, 30.0, 120.0)
    assert r.shape[0] == (pos.shape[0] - 1) * 4 + 1
    np.testing.assert_allclose(r[::4][m[::4]], pos[m[::4]])  # source frames are kept exactly
    wins, masks, starts = cut_windows(r, m, 64, 32)
    covered = np.zeros(r.shape[0], bool)
    for s in starts:
        covered[s : s + 64] = True
    assert covered.all() and starts[-1] == r.shape[0] - 64
    short, short_m, _ = cut_windows(pos[:10], obs[:10], 64)
    assert short.shape == (1, 64, 25, 3) and not short_m[0, 10:].any()


def test_cmu_marker_takes_become_upright_kinect_bodies(shared_data):
    from streamfix.prior.data import marker_take

    take = marker_take(shared_data / "c3d" / "85_02.c3d")
    assert take.positions.shape[1:] == (25, 3) and take.observed.all()
    up = take.positions[:, KINECT_V2.index("Head")] - take.positions[:, KINECT_V2.index("SpineBase")]
    assert np.median(up[:, 1]) > 0.3  # y-up like BVH and Kinect camera space
    # not mirrored: (left hip - right hip) x up points where the feet point, as on a BVH take and a Kinect recording
    from streamfix.prior.data import load_take

    def handedness(p):
        fwd = (p[:, 15] - p[:, 14]) + (p[:, 19] - p[:, 18])
        return np.sign(np.nanmedian(np.einsum("ti,ti->t", np.cross(p[:, 12] - p[:, 16], p[:, 3] - p[:, 0]), fwd)))

    bvh = load_take(shared_data / "cmu_bvh" / "131_01.bvh").positions
    kinect = load_take(shared_data / "kinect_v2" / "Ges01_wavehand.csv").positions
    assert handedness(take.positions) == handedness(bvh) == handedness(kinect) != 0
    assert marker_take(shared_data / "c3d" / "03_rolling.c3d") is None  # another marker set: not used
