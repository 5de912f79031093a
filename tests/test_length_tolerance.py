"""The bone projection's length band (core.length_tolerance and stage 5 of the window cleaner).

Real data: the KERAAL Kinect v2 + Vicon take (the paired protocol's ground truth) and
CMU 131_02 retargeted to the Kinect v2 joints at 30 Hz with the sensor protocol's spikes."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import bone_projection, kernels, metrics
from streamfix.core.length_tolerance import length_targets, length_tolerance
from streamfix.core.bone_projection import project_bone_lengths_pbd
from streamfix.core.pipeline import PipelineConfig
from streamfix.core.reference_metrics import remove_mean_offset
from streamfix.evaluation.paired import body_region
from streamfix.evaluation.sensor import _rng, ground_truth
from streamfix.motion import Motion
from streamfix.sim.sensor_errors import apply_sensor_errors
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.config import schedule_config
from streamfix.streaming.offline import clean_motion

BONES = np.array([[0, 1], [1, 2], [1, 3]])
LENGTHS = np.array([0.3, 0.25, 0.4])


def test_band_is_the_length_share_less_the_noise_on_trusted_ends_only():
    T = 4
    noise = np.array([0.001, 0.002, 0.0, 0.01])
    conf = np.ones((T, 4))
    conf[1, 2] = 0.5                      # joint 2 inferred in frame 1
    trusted = np.ones((T, 4), dtype=bool)
    trusted[2, 3] = False                 # joint 3 an outlier (or missing) in frame 2
    band = length_tolerance(BONES, LENGTHS, noise, conf, trusted, fraction=0.04, noise_multiple=2.0)
    assert band.shape == (T, 3)
    expected = np.maximum(0.0, 0.04 * LENGTHS - 2.0 * np.sqrt(noise[BONES[:, 0]] ** 2 + noise[BONES[:, 1]] ** 2))
    assert np.allclose(band[0], expected)
    assert expected[2] == 0.0             # a noisy end (1 cm) closes the band: the exact projection
    assert band[1, 1] == 0.0 and band[1, 0] == expected[0]   # the inferred end's bone only
    assert band[2, 2] == 0.0 and band[2, 1] == expected[1]
    nan_length = length_tolerance(BONES, np.array([0.3, np.nan, 0.4]), noise, conf, trusted)
    assert np.all(nan_length[:, 1] == 0.0)


def _scaled_chain(x: np.ndarray, factors: tuple[float, float, float]) -> np.ndarray:
    """``x`` with each bone of ``BONES`` set to ``factor x LENGTHS`` along its own direction."""
    y = x.copy()
    for (p, c), length, f in zip(BONES, LENGTHS, factors):
        u = x[:, c] - x[:, p]
        y[:, c] = y[:, p] + u * (length * f / np.linalg.norm(u, axis=1))[:, None]
    return y


def test_targets_keep_the_bones_own_length_inside_the_band_and_its_edge_outside():
    rng = np.random.default_rng(7)
    T = 30
    x = _scaled_chain(rng.normal(scale=0.3, size=(T, 4, 3)), (1.02, 0.98, 1.2))
    band = np.full((T, 3), 0.01)
    band[:, 1] = 0.0                                   # an untrusted end: the length itself
    targets = length_targets(x, BONES, LENGTHS, band)
    assert np.allclose(targets[:, 0], 1.02 * LENGTHS[0])  # 6 mm over, inside the 1 cm band: kept
    assert np.allclose(targets[:, 1], LENGTHS[1])
    assert np.allclose(targets[:, 2], LENGTHS[2] + 0.01)        # 8 cm over: the band's edge
    # smoothed over time, the slow play is kept and the frame-to-frame part removed,
    # never beyond the band
    slow = 0.005 * np.sin(np.arange(T) / 5.0)
    play = slow + 0.004 * (-1.0) ** np.arange(T)
    wobble = np.concatenate([_scaled_chain(x[t:t + 1], (1 + play[t] / LENGTHS[0], 1.0, 1.0)) for t in range(T)])
    smooth = length_targets(wobble, BONES, LENGTHS, np.full((T, 3), 0.02), smooth_frames=5)[:, 0] - LENGTHS[0]
    inner = slice(5, T - 5)
    assert np.abs(smooth[inner] - slow[inner]).max() < 0.002
    assert np.abs(smooth[inner] - play[inner]).max() > 0.003
    assert np.abs(smooth).max() <= 0.02 + 1e-12
    nan_length = length_targets(x, BONES, np.array([0.3, np.nan, 0.4]), band)
    assert np.isnan(nan_length[:, 1]).all()


def test_projection_reaches_per_frame_targets_and_leaves_kept_bones_alone():
    rng = np.random.default_rng(7)
    T = 30
    x = rng.normal(scale=0.3, size=(T, 4, 3))
    targets = length_targets(x, BONES, LENGTHS, np.full((T, 3), 0.01))
    y = project_bone_lengths_pbd(x, BONES, targets, 200, None)
    assert np.abs(metrics.bone_lengths(y, BONES) - targets).max() < 1e-4
    # a pose whose bones are all within the band is left as it is
    x_in = _scaled_chain(x, (1.02, 0.98, 1.01))
    kept = length_targets(x_in, BONES, LENGTHS, np.full((T, 3), 0.04 * LENGTHS.max()))
    assert np.abs(project_bone_lengths_pbd(x_in, BONES, kept, 200, None) - x_in).max() < 1e-12
    # one length for every frame: the exact projection as before
    exact = project_bone_lengths_pbd(x, BONES, LENGTHS, 200, None)
    assert np.abs(metrics.bone_lengths(exact, BONES) - LENGTHS).max() < 1e-4


def test_kernel_matches_the_numpy_reference_with_per_frame_targets():
    if not kernels.COMPILED:
        pytest.skip("numba not available: only the numpy reference runs")
    rng = np.random.default_rng(11)
    x = rng.normal(scale=0.3, size=(50, 4, 3))
    targets = LENGTHS[None, :] + rng.uniform(-0.02, 0.02, size=(50, 3))
    targets[:, 1] = np.nan                # a bone without a length is left alone
    inv_mass = rng.uniform(0.5, 2.0, size=(50, 4))
    got = kernels.project_bone_lengths_pbd(x, BONES, targets, 40, inv_mass)
    ref = bone_projection.project_bone_lengths_pbd(x, BONES, targets, 40, inv_mass)
    assert np.abs(got - ref).max() < 1e-12
    assert np.abs(got - x).max() > 1e-3


def _lower_error(take, y) -> float:
    ref = take.reference
    lower = np.array([body_region(n) == "lower" for n in take.sensor.skeleton.joint_names])
    err = np.linalg.norm(remove_mean_offset(y, ref) - ref, axis=2)[:, lower]
    return float(np.nanmean(err))


def test_kinect_legs_are_not_moved_off_the_vicon_by_their_length_play(keraal):
    """KERAAL's tracked shin varies by ~1 cm with the pose while the ankle is within 3 mm of
    the Vicon; pulled to one length, the ankles ended further from the truth than the raw
    sensor's. With the band the cleaned legs are at least as close to the Vicon as raw."""
    m = keraal.sensor
    raw = _lower_error(keraal, m.positions)

    def cleaned(tolerance: float) -> float:
        config = schedule_config("file", m.rate_hz, solver_config=PipelineConfig(projection_tolerance=tolerance))
        return _lower_error(keraal, clean_motion(m, config)[0].positions)

    assert cleaned(0.0) > 1.05 * raw      # the defect this guards against is there to see
    assert cleaned(PipelineConfig().projection_tolerance) <= raw


def test_exact_frames_around_spikes_are_left_alone(shared_data):
    """Sensor protocol, spikes on exact mocap: the frames the sensor got right stay put."""
    path = shared_data / "cmu_bvh" / "131_02.bvh"
    truth = ground_truth(path).positions
    c = apply_sensor_errors(truth, _rng(0, "spike", path), ["spike"], rate_hz=30.0, min_events=1)
    exact = ~c.corrupted

    def collateral(tolerance: float) -> float:
        config = schedule_config("file", 30.0, solver_config=PipelineConfig(projection_tolerance=tolerance))
        motion = Motion(c.positions, c.confidence, np.arange(len(truth)) / 30.0, 30.0, KINECT_V2)
        y = clean_motion(motion, config)[0].positions
        return float(np.linalg.norm(y - truth, axis=2)[exact].mean())

    before, after = collateral(0.0), collateral(PipelineConfig().projection_tolerance)
    assert after < 0.5 * before
    assert after < 0.0005                 # half a millimetre on exact samples
