"""The default streamfix pipeline (clean_window) on real mocap and real Kinect data."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import metrics
from streamfix.core.corruption import add_noise, apply_gaps, gap_mask
from streamfix.core.filters import median_savgol
from streamfix.core.interpolate import interpolate_linear
from streamfix.core.pipeline import PipelineConfig, WindowResult, clean_window
from streamfix.io.bvh import read_bvh
from streamfix.io.kinect_csv import read_kinect_csv


@pytest.fixture(scope="module")
def cmu30(shared_data):
    m = read_bvh(shared_data / "cmu_bvh" / "131_02.bvh")
    return m.positions[::4][:200], m.skeleton.bone_array  # 120 -> 30 Hz, 200 frames


def test_no_corruption_output_equals_input(cmu30):
    gt, bones = cmu30
    r = clean_window(gt, None, bones, None, 30.0)
    assert isinstance(r, WindowResult)
    assert r.positions.shape == gt.shape
    assert metrics.aje(r.positions, gt) < 1e-3
    assert r.recovered.mean() < 0.05  # few false alarms (fast feet at 30 Hz)


def test_outliers_are_rejected(cmu30):
    gt, bones = cmu30
    noisy, mask = add_noise(gt, 0.1, np.random.default_rng(5))
    r = clean_window(noisy, None, bones, None, 30.0)
    err = np.linalg.norm(r.positions - gt, axis=2)
    big = np.abs(noisy - gt).max(axis=2) > 0.05  # joint-frames with a clearly visible outlier
    assert r.recovered[big].mean() > 0.95  # detected ...
    assert err[big].mean() < 0.01  # ... and replaced by something close to the truth
    assert metrics.aje(r.positions, gt) < 0.5 * metrics.aje(median_savgol(noisy, 30.0), gt)


@pytest.mark.parametrize("n_frames", [50, 120, 300])
def test_runs_on_windows_of_50_to_300_frames(shared_data, n_frames):
    m = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh")
    gt = m.positions[100:100 + n_frames]
    noisy, _ = add_noise(gt, 0.2, np.random.default_rng(n_frames))
    r = clean_window(noisy, None, m.skeleton.bone_array, None, 120.0)
    assert np.isfinite(r.positions).all()
    assert metrics.aje(r.positions, gt) < 0.010  # Table II total at 20 %: 0.010 m


def test_gaps_are_filled_better_than_linear(cmu30):
    gt, bones = cmu30
    missing = gap_mask(*gt.shape[:2], 0.1, np.random.default_rng(2))
    x, obs = apply_gaps(gt, missing)
    r = clean_window(x, obs.astype(float), bones, None, 30.0, PipelineConfig(solver_max_iter=100))
    assert np.isfinite(r.positions).all()
    assert r.recovered[missing].all()
    lin = interpolate_linear(x, obs)[0]
    assert metrics.gap_mae(r.positions, gt, missing) < metrics.gap_mae(lin, gt, missing)


def test_kinect_jitter_and_bone_stability(shared_data):
    m = read_kinect_csv(shared_data / "kinect_v2" / "seated_joints.csv")
    x, obs, bones = m.positions, m.observed, m.skeleton.bone_array
    r = clean_window(x, m.confidence, bones, None, m.rate_hz)
    y = np.where(obs[..., None], r.positions, np.nan)
    ms = np.where(obs[..., None], median_savgol(x, m.rate_hz, obs), np.nan)
    assert metrics.jitter(y) <= metrics.jitter(ms)
    assert metrics.bone_length_cv(y, bones) < 0.5 * metrics.bone_length_cv(x, bones)
    # inferred joints are kept as (down-weighted) observations, not dragged away
    inferred = obs & (m.confidence < 1)
    shift = np.linalg.norm(r.positions - x, axis=2)[inferred]
    assert np.median(shift) < 0.05


def test_bad_shapes_are_named():
    with pytest.raises(ValueError, match="confidence must be"):
        clean_window(np.zeros((10, 3, 3)), np.ones((10, 4)), np.array([[0, 1]]), None, 30.0)
    with pytest.raises(ValueError, match=r"\(T, J, 3\)"):
        clean_window(np.zeros((10, 3)), None, np.array([[0, 1]]), None, 30.0)


def test_heavy_corruption_80_percent_at_120hz(shared_data):
    # the paper's model fails here (its optimum is far from the truth); the robust stage does not
    m = read_bvh(shared_data / "cmu_bvh" / "131_02.bvh")
    gt = m.positions[200:500]
    noisy, _ = add_noise(gt, 0.8, np.random.default_rng(80))
    r = clean_window(noisy, None, m.skeleton.bone_array, None, 120.0)
    assert metrics.aje(r.positions, gt) < 0.040  # the bar at 80 %
    assert metrics.aje(r.positions, gt) < 0.6 * metrics.aje(median_savgol(noisy, 120.0), gt)


def test_the_median_alone_is_not_taken_where_it_flattens_fast_motion(shared_data):
    """Xia's short stylised takes (fast punches, a kick) as Kinect v2 joints with the sensor
    protocol's noise on every sample: the running median + Savitzky-Golay scores more rigid
    (the noise) while it flattens the motion, which keeps bones rigid too. Its residual, over
    1.5x the fit's, says so: the fit stays. Under the paper's 80 % corruption the fit's
    residual is as large as the median's, which stays eligible there."""
    from streamfix.evaluation.sensor import ground_truth
    from streamfix.sim.sensor_errors import apply_sensor_errors
    from streamfix.skeletons import KINECT_V2

    for name, seed in (("angry_13_000", 2), ("neutral_16_000", 0)):
        truth = ground_truth(shared_data / "xia_bvh" / f"{name}.bvh", 30.0).positions
        c = apply_sensor_errors(truth, np.random.default_rng(seed), ["noise"], rate_hz=30.0, min_events=1)
        gated = clean_window(c.positions, c.confidence, KINECT_V2.bone_array, None, 30.0)
        # (the worst-bone test below also vetoes it here: both off, the median is taken)
        free = clean_window(c.positions, c.confidence, KINECT_V2.bone_array, None, 30.0,
                            PipelineConfig(fallback_max_residual_ratio=None, fallback_worst_bone_quantile=None))
        assert free.info["estimator"] == "median_savgol"
        assert gated.info["estimator"] != "median_savgol" and gated.info["median_residual_ratio"] > 1.5
        err = {k: np.linalg.norm(r.positions - truth, axis=2).mean() for k, r in (("gated", gated), ("free", free))}
        assert err["gated"] < 0.95 * err["free"], err  # measured 13.6 vs 17.4 and 14.0 vs 15.4 mm
    m = read_bvh(shared_data / "cmu_bvh" / "131_02.bvh")
    gt = m.positions[::4][50:350]
    noisy, _ = add_noise(gt, 0.8, np.random.default_rng(80))
    r = clean_window(noisy, None, m.skeleton.bone_array, None, 30.0)
    assert r.info["median_residual_ratio"] < PipelineConfig().fallback_max_residual_ratio  # measured 0.76


def test_window_choice_prefers_rigid_bones(cmu30):
    # one half-width per window (local_width_s=None): the chosen candidate is the one with
    # the least bone-length spread, and on clean-ish data the shortest window (least bias)
    # wins the tie
    gt, bones = cmu30
    noisy, _ = add_noise(gt, 0.05, np.random.default_rng(9))
    r = clean_window(noisy, None, bones, None, 30.0, PipelineConfig(local_width_s=None))
    spreads = r.info["bone_spread_m"]
    assert spreads[r.info["estimator"]] == min(spreads.values())
    h = r.info["half_width_frames"]
    windows = {k: v for k, v in spreads.items() if isinstance(k, int)}
    assert h == min(k for k, v in windows.items() if v == min(windows.values()))


@pytest.mark.parametrize("seed", [0, 3])
def test_half_width_is_chosen_per_frame_where_the_corruption_is(cmu30, seed):
    # the first half of the window is corrupted (30 % of coordinates, +-25 cm), the second
    # exact: each part takes its own half-width (wide where the fit must reject outliers,
    # the shortest where it need not), which one half-width for the window cannot
    gt, bones = cmu30
    gt = gt[:120]
    noisy = gt.copy()
    noisy[:60], _ = add_noise(gt[:60], 0.3, np.random.default_rng(seed))
    r = clean_window(noisy, None, bones, None, 30.0)
    one = clean_window(noisy, None, bones, None, 30.0, PipelineConfig(local_width_s=None))
    widths = r.info["local_half_width_frames"]
    assert widths.shape == (120,)
    assert widths[:55].mean() > widths[65:].mean() + 1.5
    assert widths[65:].mean() < 3.5  # near the shortest candidate (2 frames at 30 Hz)
    assert metrics.aje(r.positions, gt) < 0.6 * metrics.aje(one.positions, gt)
    # the estimator is still the candidate with the least bone-length spread
    spreads = r.info["bone_spread_m"]
    assert spreads[r.info["estimator"]] == min(spreads[k] for k in ("local", "median_savgol", "blend"))


@pytest.mark.parametrize("start,frames", [(30, 5), (50, 3)])
def test_a_hand_thrown_for_a_few_frames_on_exact_data_is_removed(shared_data, start, frames):
    """A walking body's (CMU 131_01 as Kinect v2 joints, exact) left hand thrown 19 cm for
    3-5 frames: the per-frame half-width takes a wide fit there, which rejects it (the hand's
    own bones to the wrist and the hand tip stretch where a short fit follows it)."""
    from streamfix.evaluation.sensor import ground_truth
    from streamfix.skeletons import KINECT_V2

    truth = ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", 30.0).positions[:90]
    hand = KINECT_V2.joint_names.index("HandLeft")
    x = truth.copy()
    x[start:start + frames, hand] += np.array([0.12, -0.10, 0.11])
    thrown = float(np.linalg.norm(x[start:start + frames, hand] - truth[start:start + frames, hand], axis=1).mean())

    def error(config: PipelineConfig = PipelineConfig()) -> float:
        r = clean_window(x, np.ones(x.shape[:2]), KINECT_V2.bone_array, None, 30.0, config)
        return float(np.linalg.norm(r.positions[start:start + frames, hand] - truth[start:start + frames, hand],
                                    axis=1).mean())

    fixed = error()
    assert fixed < 0.15 * thrown
    # one half-width for the whole window: the window's score takes a short fit, which follows the hand
    assert error(PipelineConfig(local_width_s=None)) > 2 * fixed


def test_the_median_does_not_stand_alone_where_it_follows_a_jumping_forearm(shared_data):
    """A 10 s window of CMU 131_02 (Kinect v2 joints) with 4 mm of white noise on every
    sample and the left forearm and hand jumping 17 cm for 6 frames: the running median +
    Savitzky-Golay smooths the noise, so its bones are the most rigid by their median over
    time, which ignores the 6 frames; it follows the jump there, and the worst bone of those
    frames shows it. The per-frame fit rejects the jump."""
    from streamfix.evaluation.sensor import ground_truth
    from streamfix.skeletons import KINECT_V2

    truth = ground_truth(shared_data / "cmu_bvh" / "131_02.bvh", 30.0).positions[:300]
    x = truth + np.random.default_rng(1).normal(0.0, 0.004, truth.shape)
    arm = [KINECT_V2.index(n) for n in ("ElbowLeft", "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft")]
    x[150:156, arm] += np.array([0.0, 0.12, 0.12])

    def run(config: PipelineConfig) -> tuple[str, float]:
        r = clean_window(x, np.ones(x.shape[:2]), KINECT_V2.bone_array, None, 30.0, config)
        err = np.linalg.norm(r.positions[150:156, arm] - truth[150:156, arm], axis=2).mean()
        return r.info["estimator"], float(err)

    chosen, err = run(PipelineConfig())
    old_chosen, old_err = run(PipelineConfig(fallback_worst_bone_quantile=None))
    assert old_chosen == "median_savgol" and old_err > 0.12   # the jump left in
    assert chosen != "median_savgol" and err < 0.5 * old_err


@pytest.mark.xfail(strict=True, reason="known limitation: a limb thrown rigidly stretches one bone only")
def test_a_forearm_thrown_rigidly_for_a_few_frames_is_removed(shared_data):
    """Known failure of the window cleaner alone: a forearm-and-hand group (CMU 131_02, exact)
    offset together by 16 cm for 3 frames keeps its own bones and stretches only the upper arm,
    by 2.5 cm, which a frame's mean over 24 bones dilutes: the shortest fit follows the group at
    its middle frame. Keeping the per-frame choice only where the window as a whole was as rigid
    removed it, but cost more on the sensor protocol's jumps and spikes, the paper's noise
    protocol and the paired recordings than it gained there (benchmarks/results/). What users
    get does remove it: the engine's bridge releases such a group before the window cleaner
    runs (core/limb_jumps.py, tests/test_limb_jumps.py)."""
    from streamfix.evaluation.sensor import ground_truth

    m = ground_truth(shared_data / "cmu_bvh" / "131_02.bvh")
    truth = m.positions[100:160]
    arm = [m.skeleton.index(n) for n in ("ElbowLeft", "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft")]
    x = truth.copy()
    x[28:31, arm] += np.array([0.0, 0.15, 0.05])
    r = clean_window(x, np.ones(x.shape[:2]), m.skeleton.bone_array, None, m.rate_hz)
    err = np.linalg.norm(r.positions[28:31, arm] - truth[28:31, arm], axis=2).max()
    assert err < 0.5 * np.linalg.norm([0.15, 0.05])


def test_pbd_projection_reaches_lengths_and_moves_low_confidence_more():
    from streamfix.core.bone_projection import project_bone_lengths_pbd

    rng = np.random.default_rng(4)
    bones = np.array([[0, 1], [1, 2], [1, 3]])
    target = np.array([0.3, 0.25, 0.4])
    x = rng.normal(scale=0.3, size=(20, 4, 3))
    inv_mass = np.ones((20, 4))
    inv_mass[:, 2] = 2.0  # joint 2 inferred: half the confidence, twice the move
    y = project_bone_lengths_pbd(x, bones, target, 200, inv_mass)
    lengths = metrics.bone_lengths(y, bones)
    assert np.abs(lengths - target).max() < 1e-4
    move = np.linalg.norm(y - x, axis=2)
    # on bone (1, 2) the inferred end takes the larger share of the correction
    assert np.median(move[:, 2] / np.maximum(move[:, 1], 1e-12)) > 1.0


def _local_poly_by_lapack(y, w, h):
    """The local quadratic fit of stage 1 with every 3x3 system solved by LAPACK (LU)."""
    from scipy.ndimage import correlate1d

    k = np.arange(-h, h + 1, dtype=np.float64)
    K = (1.0 - (np.abs(k) / (h + 1)) ** 3) ** 3
    u = k / h
    S = [correlate1d(w, K * u**m, axis=0, mode="constant") for m in range(5)]
    R = [correlate1d(w * y, K * u**m, axis=0, mode="constant") for m in range(3)]
    M = np.empty(y.shape + (3, 3))
    for a in range(3):
        for b in range(3):
            M[..., a, b] = S[a + b]
    M[..., 0, 0] += 1e-12
    M[..., 1, 1] += 1e-9
    M[..., 2, 2] += 1e-9
    return np.linalg.solve(M, np.stack(R, axis=-1)[..., None])[..., 0, 0]


@pytest.mark.parametrize("h", [2, 4, 9])
def test_local_poly_closed_form_matches_lapack_solve(cmu30, h):
    # the closed-form LDL^T (with LU where a pivot cancelled) gives LAPACK's fit on real
    # mocap with Tukey-like weights, zero-weight runs and windows holding 1-2 samples
    from streamfix.core.local_poly import local_poly_numpy

    gt, _ = cmu30
    rng = np.random.default_rng(h)
    y = gt[:60].reshape(60, -1)
    w = rng.uniform(0, 1, size=y.shape) * (rng.random(y.shape) < 0.6)
    w[10:30, :5] = 0.0          # nothing in the window
    w[40:60, 5:10] = 0.0
    w[45, 5:10] = 0.7           # a lone sample
    w[50:52, 6] = 1.0           # two samples
    fit, support = local_poly_numpy(y, w, h)
    ref = _local_poly_by_lapack(y, w, h)
    assert np.abs(fit - ref).max() < 1e-9
    assert np.all(support >= 0) and np.all(support[10 + h:30 - h, :5] == 0)


def test_joint_missing_for_the_whole_window_is_recovered_not_a_crash(shared_data):
    """A Kinect hand untracked for a whole window (2 s) must come back finite and flagged.

    Regression: Savitzky-Golay inside the median fallback raised on the all-NaN channel.
    """
    motion = read_kinect_csv(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    x = motion.positions[:60].copy()
    conf = motion.confidence[:60].copy()
    hand = 7  # HandLeft
    x[:, hand] = np.nan
    conf[:, hand] = 0.0
    res = clean_window(x, conf, motion.skeleton.bone_array, None, motion.rate_hz)
    assert np.isfinite(res.positions).all()
    assert res.recovered[:, hand].all()
    others = np.ones(x.shape[1], bool)
    others[hand] = False
    # every other joint stays where the sensor saw it (within the pipeline's smoothing)
    assert np.nanmax(np.abs(res.positions[:, others] - motion.positions[:60, others])) < 0.1


def test_estimators_are_scored_on_the_newest_frames_plus_the_widest_kernel():
    from streamfix.core.pipeline import _scored_frames

    assert _scored_frames(60, None, 9) == slice(None)
    assert _scored_frames(60, 30, 9) == slice(21, None)  # 30 + 9 newest of 60
    assert _scored_frames(90, 115, 9) == slice(None)  # the file schedule: the whole window
    assert _scored_frames(16, 30, 9) == slice(None)  # a stream's first, short windows
