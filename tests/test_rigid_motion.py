"""Fast real motion is kept, outliers are not (core.rigid_motion and the pipeline's stage 2).

Real data: Xia's neutral_16_000 (a fast arm movement, exact animation retargeted to the
Kinect v2 joints at 30 Hz) and a real Kinect v2 recording."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import isometry, kernels
from streamfix.core.pipeline import PipelineConfig, clean_window
from streamfix.core.rigid_motion import rigid_motion
from streamfix.evaluation.sensor import ground_truth
from streamfix.io.kinect_csv import read_kinect_csv

ARM_L = ("ElbowLeft", "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft")


@pytest.fixture(scope="module")
def fast_take(shared_data):
    return ground_truth(shared_data / "xia_bvh" / "neutral_16_000.bvh")


def _clean(m, x, keep: bool):
    """Stage 2 with and without the rigidity test, after one fit per window: the per-frame
    half-width (``local_width_s``) follows most fast motion itself, which would hide what
    the test is for."""
    cfg = PipelineConfig(keep_rigid_motion=keep, local_width_s=None)
    return clean_window(x, np.ones(x.shape[:2]), m.skeleton.bone_array, None, m.rate_hz, cfg)


def test_fast_exact_motion_is_kept(fast_take):
    """The fit cannot follow the hand; without the test it replaced exact samples by decimetres."""
    m, x = fast_take, fast_take.positions
    off = np.linalg.norm(_clean(m, x, False).positions - x, axis=2)
    res = _clean(m, x, True)
    on = np.linalg.norm(res.positions - x, axis=2)
    assert off.max() > 0.15  # the defect this guards against is there to see
    assert res.info["rigid_motion_kept"] > 0
    assert on.max() < 0.3 * off.max() and on.mean() < 0.3 * off.mean()


@pytest.fixture(scope="module")
def calm_window(shared_data):
    m = ground_truth(shared_data / "cmu_bvh" / "131_02.bvh")
    return m, m.positions[100:160]


def _corrupted_as_without(m, truth, x, where):
    """The rigidity test leaves the samples at ``where`` flagged (recovered), as they are
    without it; the input's and the output's errors there. (The outputs with and without
    the test may differ by millimetres: the test keeps fast motion elsewhere in the window,
    and the bone projection shares length errors by which samples are flagged.)"""
    on_result, off_result = _clean(m, x, True), _clean(m, x, False)
    assert on_result.recovered[where].all() and off_result.recovered[where].all()
    on = on_result.positions
    np.testing.assert_allclose(on[where], off_result.positions[where], atol=0.01)  # replaced alike, to a centimetre
    return (np.linalg.norm(x[where] - truth[where], axis=-1).mean(),
            np.linalg.norm(on[where] - truth[where], axis=-1).mean())


def test_spike_is_still_an_outlier(calm_window):
    m, truth = calm_window
    x = truth.copy()
    where = (30, [m.skeleton.index("HandLeft")])
    x[where] += np.array([0.06, -0.05, 0.04])  # one frame, ~9 cm
    err_in, err_out = _corrupted_as_without(m, truth, x, where)
    assert err_out < 0.3 * err_in


def test_thrown_distal_limb_is_still_an_outlier(calm_window):
    """A forearm-and-hand group offset together keeps its own bones but breaks the upper arm's."""
    m, truth = calm_window
    x = truth.copy()
    where = (slice(28, 31), [m.skeleton.index(n) for n in ARM_L])
    x[where] += np.array([0.0, 0.15, 0.05])
    err_in, err_out = _corrupted_as_without(m, truth, x, where)
    assert err_out < 0.5 * err_in


def test_whole_body_group_and_unrigid_skeletons_are_not_judged(fast_take):
    m, x = fast_take, fast_take.positions
    bones = m.skeleton.bone_array
    flagged = np.zeros(x.shape[:2], dtype=bool)
    flagged[10] = True  # every joint of a frame: no bone hangs it on the rest of the body
    shifted = x.copy()
    shifted[10] += 0.1
    assert not rigid_motion(shifted, x, flagged, np.ones_like(flagged), bones, 0.02).any()
    # the same fast arm, kept on the exact skeleton, is not judged once the bones vary by ~1 cm
    arm = [m.skeleton.index(n) for n in ARM_L]
    flagged = np.zeros(x.shape[:2], dtype=bool)
    flagged[10, arm] = True
    smooth = x.copy()
    smooth[10, arm] = 0.5 * (x[9, arm] + x[11, arm])
    assert rigid_motion(x, smooth, flagged, np.ones_like(flagged), bones, 0.02).any()
    noisy = x + np.random.default_rng(0).normal(0.0, 0.006, x.shape)
    assert not rigid_motion(noisy, np.where(flagged[..., None], smooth, noisy), flagged, np.ones_like(flagged),
                            bones, 0.02).any()


def test_fast_arm_is_kept_next_to_a_frozen_leg(fast_take):
    """A limb's worth of varying bones (the left leg frozen at its first pose, on a skeleton
    whose retargeted hand bones already vary by millimetres) does not make the exact skeleton
    a depth sensor's: the fast left arm is still judged, and kept."""
    m = fast_take
    x = m.positions.copy()
    leg = [m.skeleton.index(n) for n in ("KneeLeft", "AnkleLeft", "FootLeft")]
    x[:, leg] = x[0, leg]
    arm = [m.skeleton.index(n) for n in ARM_L]
    flagged = np.zeros(x.shape[:2], dtype=bool)
    flagged[10, arm] = True
    smooth = x.copy()
    smooth[10, arm] = 0.5 * (x[9, arm] + x[11, arm])
    assert rigid_motion(x, smooth, flagged, np.ones_like(flagged), m.skeleton.bone_array, 0.02)[10, arm].all()


def test_spiked_joint_of_a_fast_arm_stays_flagged_and_the_arm_is_kept(fast_take):
    """A spike on the thumb of a fast hand breaks only the thumb's bone: the thumb is the
    outlier and stays flagged, the rest of the flagged arm is judged without it and kept.
    Judged as one group, the thumb's broken bone had the whole fast arm replaced by the fit
    (0.1-0.2 m off for the frame on the sensor protocol's spike kind)."""
    m = fast_take
    x = m.positions.copy()
    thumb = m.skeleton.index("ThumbLeft")
    x[10, thumb] += np.array([0.05, -0.06, 0.04])
    arm = [m.skeleton.index(n) for n in ARM_L]
    flagged = np.zeros(x.shape[:2], dtype=bool)
    flagged[10, arm] = True
    smooth = x.copy()
    smooth[10, arm] = 0.5 * (x[9, arm] + x[11, arm])
    kept = rigid_motion(x, smooth, flagged, np.ones_like(flagged), m.skeleton.bone_array, 0.02)
    assert not kept[10, thumb]
    assert kept[10, [j for j in arm if j != thumb]].all()


def test_depth_sensor_windows_keep_the_fits_verdict(shared_data):
    m = read_kinect_csv(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    kept = 0
    for a in range(0, m.n_frames - 60, 30):
        res = clean_window(m.positions[a:a + 60], m.confidence[a:a + 60], m.skeleton.bone_array, None, m.rate_hz)
        kept += res.info.get("rigid_motion_kept", 0)
    assert kept == 0


def test_bone_length_deviations_numpy_reference_matches_kernel(fast_take, monkeypatch):
    if not kernels.COMPILED:
        pytest.skip("numba kernels not compiled")
    x = fast_take.positions + np.random.default_rng(1).normal(0.0, 0.003, fast_take.positions.shape)
    obs = np.random.default_rng(2).random(x.shape[:2]) > 0.2
    bones = fast_take.skeleton.bone_array
    compiled = isometry.bone_length_deviations(x, obs, bones, 0.02)
    monkeypatch.setattr(kernels, "COMPILED", False)
    reference = isometry.bone_length_deviations(x, obs, bones, 0.02)
    np.testing.assert_array_equal(np.isnan(compiled), np.isnan(reference))
    np.testing.assert_allclose(compiled[np.isfinite(compiled)], reference[np.isfinite(reference)], rtol=0, atol=1e-15)
