"""Metrics on hand-made cases (Yang et al. Section IV definitions)."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import metrics

BONES = np.array([[0, 1], [1, 2]])


def _chain(n=4):
    x = np.zeros((n, 3, 3))
    x[:, 1, 0] = 1.0
    x[:, 2, 0] = 3.0  # bones of length 1 and 2
    return x


def test_aje_is_mean_euclidean_distance():
    gt = _chain()
    pred = gt.copy()
    pred[0, 0] += [3.0, 4.0, 0.0]  # one joint-frame off by 5 m
    assert metrics.aje(pred, gt) == pytest.approx(5.0 / 12)


def test_abe_mean_over_bones_and_frames():
    gt = _chain()
    pred = gt.copy()
    pred[1, 2, 0] = 3.5  # second bone 0.5 m too long in one frame
    assert metrics.abe(pred, gt, BONES) == pytest.approx(0.5 / 8)
    # a rigid translation changes AJE but not ABE
    moved = gt + np.array([0.1, 0.2, 0.3])
    assert metrics.abe(moved, gt, BONES) == pytest.approx(0.0, abs=1e-12)
    assert metrics.aje(moved, gt) == pytest.approx(np.sqrt(0.14))


def test_jitter_zero_for_linear_motion_and_units_per_frame():
    t = np.arange(10, dtype=float)
    x = np.zeros((10, 1, 3))
    x[:, 0, 0] = 0.1 * t
    assert metrics.jitter(x) == pytest.approx(0.0, abs=1e-12)
    x[5, 0, 1] = 0.01  # one bump: three second differences of magnitude .01, .02, .01
    assert metrics.jitter(x) == pytest.approx(0.04 / 8)


def test_bone_length_cv():
    x = _chain(2)
    x[1, 2, 0] = 4.0  # bone 2: lengths 2 and 3 -> std 0.5, mean 2.5
    assert metrics.bone_length_cv(x, BONES) == pytest.approx((0 + 0.5 / 2.5) / 2)
    assert metrics.bone_length_cv(_chain(), BONES) == pytest.approx(0.0)


def test_gap_mae_only_over_missing():
    gt = _chain()
    pred = gt.copy()
    pred[2, 1] += [0.0, 0.3, 0.0]
    pred[0, 0] += [1.0, 0.0, 0.0]  # not in the gap: must not count
    missing = np.zeros((4, 3), bool)
    missing[2, 1] = missing[3, 1] = True
    assert metrics.gap_mae(pred, gt, missing) == pytest.approx(0.15)


def test_metrics_ignore_nan_and_check_shapes():
    gt = _chain()
    pred = gt.copy()
    pred[0, 0] = np.nan
    assert metrics.aje(pred, gt) == pytest.approx(0.0)
    with pytest.raises(ValueError, match=r"\(4, 3, 3\)"):
        metrics.aje(pred[:, :2], gt)


def _two_arms(T=20, left_len=0.30, right_len=0.30):
    """Joints: 0 chest, 1 left elbow, 2 right elbow; bones chest->elbows (mirrors of each other)."""
    x = np.zeros((T, 3, 3))
    x[:, 1, 0] = -left_len
    x[:, 2, 0] = right_len
    return x


def test_inferred_bone_asymmetry_measures_the_inferred_limb_against_its_mirror():
    bones = np.array([[0, 1], [0, 2]])
    mirror = np.array([1, 0])
    inferred = np.zeros((20, 3), dtype=bool)
    inferred[5:, 1] = True  # the left elbow is guessed for 15 frames
    stretched = _two_arms(left_len=0.36)  # 20 % longer than its tracked twin
    assert metrics.inferred_bone_asymmetry(stretched, inferred, bones, mirror) == pytest.approx(0.2)
    assert metrics.inferred_bone_asymmetry(_two_arms(), inferred, bones, mirror) == pytest.approx(0.0)
    # too few inferred frames, or no mirror: nothing to judge
    few = np.zeros_like(inferred)
    few[:3, 1] = True
    assert np.isnan(metrics.inferred_bone_asymmetry(stretched, few, bones, mirror))
    assert np.isnan(metrics.inferred_bone_asymmetry(stretched, inferred, bones, np.array([0, 1])))
    with pytest.raises(ValueError, match="mirror"):
        metrics.inferred_bone_asymmetry(stretched, inferred, bones, np.array([1]))


def test_seam_sums_compare_each_seam_frame_with_its_neighbourhood():
    """Seam frames packed into the fast first second of a seamless motion: against all
    other frames they look 'seamy' (the motion, not a seam); against the other frames
    within a hop they do not. A real kink at those frames still shows either way."""
    from streamfix.core.metrics import seam_jitter, seam_sums

    t = np.arange(300) / 30.0
    amp = np.where(t < 1.0, 0.3, 0.01)  # fast first second, then slow
    x = np.zeros((300, 1, 3))
    x[:, 0, 0] = amp * np.sin(2 * np.pi * 2.0 * t)
    seam = np.zeros(300, dtype=bool)
    seam[np.r_[5:30:5, 4:30:5]] = True  # a hand-over every 5 frames in the first second
    seam[np.r_[40:300:10, 39:300:10]] = True  # then every 10
    on, off = seam_jitter(x, seam)
    assert on / off > 1.5
    on, off = seam_jitter(x, seam, radius=10)
    assert on / off == pytest.approx(1.0, abs=0.1)
    kinked = x.copy()
    kinked[:, 0, 1] = 2e-2 * np.cumsum(seam & (np.arange(300) % 5 == 0))  # a step at each hand-over
    on, off = seam_jitter(kinked, seam, radius=10)
    assert on / off > 2.0
    d2 = np.abs(np.diff(x[:, 0, 0], 2))[:, None]
    s_sum, s_n, o_sum, o_n = seam_sums(d2, seam[1:-1], radius=10)
    assert s_n == o_n == int(seam[1:-1].sum())
    with pytest.raises(ValueError, match="seam mask"):
        seam_sums(d2, seam)


def test_bone_cv_leaves_out_zero_length_links(shared_data):
    # CMU BVH hierarchies hold zero-length links (LHipJoint-style): their std / mean is
    # round-off over round-off and made a take's bone CV read 800 %
    from streamfix.io import read_motion

    m = read_motion(shared_data / "cmu_bvh" / "131_01.bvh")
    bones = m.skeleton.bone_array
    lengths = np.linalg.norm(m.positions[:, bones[:, 1]] - m.positions[:, bones[:, 0]], axis=2)
    long = lengths.mean(axis=0) >= metrics.BONE_CV_MIN_LENGTH_M
    assert not long.all(), "the take has zero-length links"
    cv = metrics.bone_length_cv(m.positions, bones)
    assert cv == pytest.approx(metrics.bone_length_cv(m.positions, bones[long])) and cv < 1e-3
    assert np.isnan(metrics.bone_length_cv(m.positions, bones[~long]))


def test_mean_move_counts_only_the_given_finite_joint_frames():
    data = np.zeros((3, 2, 3))
    out = data.copy()
    out[:, 0, 0] = 0.01  # joint 0 moved 1 cm in every frame
    out[1, 1, 2] = 0.05  # joint 1 moved 5 cm in one frame
    counted = np.ones((3, 2), dtype=bool)
    assert metrics.mean_move(out, data, counted) == pytest.approx((3 * 0.01 + 0.05) / 6)
    counted[:, 1] = False
    assert metrics.mean_move(out, data, counted) == pytest.approx(0.01)
    data[0, 0] = np.nan  # a missing input sample is no move
    assert metrics.mean_move(out, data, counted) == pytest.approx(0.01)
    assert np.isnan(metrics.mean_move(out, data, np.zeros((3, 2), dtype=bool)))
