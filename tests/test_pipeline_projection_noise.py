"""Stage 5 of clean_window: noisy joints take the bone-length correction, quiet ones keep still.

On real Kinect v2 recordings the hands, thumbs and hand tips jitter several times more
than the shoulders and spine. Split evenly between a bone's two ends, the projection's
correction carried that jitter up the arm into the trunk, and the engine's output
jittered more than median + Savitzky-Golay. On exact samples (mocap) nothing changes.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from streamfix.core import metrics
from streamfix.core.corruption import add_noise
from streamfix.core.bone_projection import joint_noise_scale, noise_share, projection_inverse_mass, smooth_projection
from streamfix.core.pipeline import PipelineConfig, clean_window
from streamfix.evaluation.registry import run_method
from streamfix.io.bvh import read_bvh
from streamfix.io.kinect_csv import read_kinect_csv

# the projection as it was: shares by confidence only, correction applied frame by frame
EVEN_SPLIT = dataclasses.replace(PipelineConfig(), projection_noise_floor_m=None)


@pytest.fixture(scope="module")
def comehere(shared_data):
    return read_kinect_csv(shared_data / "kinect_v2" / "Ges04_comehere.csv")


def _joint_jitter(y: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """``(J,)`` mean |second difference| (m/frame^2) over frames where the sensor saw the joint."""
    d2 = np.linalg.norm(y[2:] - 2 * y[1:-1] + y[:-2], axis=2)
    ok = observed[2:] & observed[1:-1] & observed[:-2]
    return np.array([d2[ok[:, j], j].mean() for j in range(y.shape[1])])


def test_kinect_noise_scale_ranks_hands_above_trunk(comehere):
    m = comehere
    r = clean_window(m.positions, m.confidence, m.skeleton.bone_array, None, m.rate_hz)
    noise = r.info["joint_noise_m"]
    names = list(m.skeleton.joint_names)
    hands = [names.index(n) for n in ("HandLeft", "HandTipLeft", "ThumbLeft")]
    trunk = [names.index(n) for n in ("SpineMid", "SpineShoulder", "ShoulderLeft", "ShoulderRight")]
    assert noise[hands].min() > 2 * noise[trunk].max(), noise
    inv = projection_inverse_mass(m.confidence, m.observed, noise, 0.001)
    assert inv[:, hands].min() > inv[:, trunk].max()  # the hands take the correction


def test_kinect_projection_keeps_the_trunk_still(comehere):
    m = comehere
    bones = m.skeleton.bone_array
    new = clean_window(m.positions, m.confidence, bones, None, m.rate_hz).positions
    old = clean_window(m.positions, m.confidence, bones, None, m.rate_hz, EVEN_SPLIT).positions
    names = list(m.skeleton.joint_names)
    trunk = [names.index(n) for n in ("SpineShoulder", "ShoulderLeft", "ShoulderRight")]
    j_new, j_old = _joint_jitter(new, m.observed), _joint_jitter(old, m.observed)
    assert j_new[trunk].mean() < 0.9 * j_old[trunk].mean(), (j_new[trunk], j_old[trunk])
    assert j_new.mean() < j_old.mean()
    # the bones still hold their lengths (the bar: CV at most 0.1x the input's);
    # what the smoothed correction leaves is frame-to-frame length noise of noisy bones
    obs = m.observed[..., None]
    cv_new = metrics.bone_length_cv(np.where(obs, new, np.nan), bones)
    cv_in = metrics.bone_length_cv(m.positions, bones)
    assert cv_new < 0.1 * cv_in, (cv_new, cv_in)


def test_engine_output_on_kinect_jitters_less_than_median_savgol(comehere):
    """What users get (the engine's clean output) against the smoother they would pick."""
    m = comehere
    bones = m.skeleton.bone_array
    obs = m.observed[..., None]
    sf = run_method("streamfix", m.positions, m.confidence, bones, m.rate_hz, skeleton=m.skeleton)
    ms = run_method("median_savgol", m.positions, m.confidence, bones, m.rate_hz)
    assert metrics.jitter(np.where(obs, sf, np.nan)) <= metrics.jitter(np.where(obs, ms, np.nan))


def test_exact_samples_keep_the_exact_projection(shared_data):
    # mocap with 10 % of entries corrupted: the kept samples are exact, so every joint's
    # noise scale is ~0, the shares stay even and the result is the old projection's
    mo = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh")
    gt = mo.positions[::4][:150]
    noisy, _ = add_noise(gt, 0.1, np.random.default_rng(11))
    bones = mo.skeleton.bone_array
    new = clean_window(noisy, None, bones, None, 30.0)
    old = clean_window(noisy, None, bones, None, 30.0, EVEN_SPLIT)
    assert new.info["joint_noise_m"].max() < 1e-3
    assert np.abs(new.positions - old.positions).max() < 2e-3
    assert metrics.aje(new.positions, gt) <= 1.05 * metrics.aje(old.positions, gt)


def test_even_noise_keeps_even_shares():
    conf = np.ones((5, 4))
    conf[:, 3] = 0.5  # inferred: moves twice as far, whatever the noise
    obs = conf > 0
    even = projection_inverse_mass(conf, obs, np.array([0.01, 0.012, 0.009, 0.011]), 0.001)
    assert np.allclose(even, 1.0 / conf)
    loud = projection_inverse_mass(conf, obs, np.array([0.002, 0.002, 0.002, 0.04]), 0.001)
    assert loud[0, 3] > 50 * loud[0, 0]
    assert np.allclose(projection_inverse_mass(conf, obs, np.zeros(4), None), 1.0 / conf)


def test_noise_scale_ignores_outliers_and_missing():
    rng = np.random.default_rng(3)
    x = np.zeros((200, 2, 3))
    x[:, 1] += rng.normal(scale=0.01, size=(200, 3))
    inlier = np.ones(x.shape, dtype=bool)
    x[::10, 0] = 5.0  # gross outliers, flagged
    inlier[::10, 0] = False
    x[5:9] = np.nan  # missing frames, not inliers
    inlier[5:9] = False
    s = joint_noise_scale(x, np.zeros_like(x), inlier)
    assert s[0] == 0.0
    assert 0.008 < s[1] < 0.012


def test_smooth_projection_only_on_noisy_joints():
    rng = np.random.default_rng(5)
    est = rng.normal(size=(60, 2, 3))
    proj = est + rng.normal(scale=0.01, size=est.shape)  # a correction that flickers frame to frame
    out = smooth_projection(est, proj, noise_share(np.array([0.0, 0.05]), 0.001), 30.0, 0.2)
    assert np.array_equal(out[:, 0], proj[:, 0])  # exact joint: exact projection
    d2 = lambda c: np.abs(np.diff(c, 2, axis=0)).mean()  # noqa: E731
    assert d2(out[:, 1] - est[:, 1]) < 0.5 * d2(proj[:, 1] - est[:, 1])
    assert np.array_equal(smooth_projection(est, proj, np.ones(2), 30.0, 0.0), proj)  # span 0: off


def test_smooth_projection_keeps_exact_correction_on_filled_samples():
    rng = np.random.default_rng(6)
    est = rng.normal(size=(60, 2, 3))
    proj = est + rng.normal(scale=0.01, size=est.shape)
    filled = np.zeros((60, 2), dtype=bool)
    filled[20:24, 1] = True  # a short fill on the noisy joint: no sensor reading behind it
    share = noise_share(np.array([0.0, 0.05]), 0.001)
    out = smooth_projection(est, proj, share, 30.0, 0.2, exact=filled)
    assert np.array_equal(out[20:24, 1], proj[20:24, 1])
    smoothed = smooth_projection(est, proj, share, 30.0, 0.2)
    assert np.array_equal(out[~filled], smoothed[~filled])  # the sensor's samples as before


def test_kinect_thumb_spike_is_filled_at_the_thumb_length(comehere):
    """Ges04's left thumb leaps 16 cm for frames 81-84 (tracked): the window replaces the
    samples; with the correction smoothed over them as well the fill kept half its length."""
    m = comehere
    bones = m.skeleton.bone_array
    names = m.skeleton.joint_names
    thumb = [b for b in range(len(bones)) if names[bones[b, 1]] == "ThumbLeft"][0]
    seg = slice(60, 120)
    lengths = np.nanmedian(metrics.bone_lengths(m.positions, bones), axis=0)
    lengths[thumb] = 0.056  # the engine's clean estimate of this thumb
    res = clean_window(m.positions[seg], m.confidence[seg], bones, lengths, m.rate_hz)
    assert res.recovered[21:25, bones[thumb, 1]].all()
    got = metrics.bone_lengths(res.positions, bones)[21:25, thumb]
    np.testing.assert_allclose(got, 0.056, atol=0.003)
