"""Paired-protocol measures on constructed cases, and the hand-over frames against the real engine."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.reference_metrics import remove_mean_offset, second_difference_norm, slow_error_norm, velocity_xcorr
from streamfix.core.rigid import fit_rigid, fit_rigid_with_offsets
from streamfix.evaluation.paired import aggregate, body_region, handover_frames, score_take
from streamfix.io.paired import PairedTake, find_takes, load_take
from streamfix.motion import Motion
from streamfix.streaming.engine import EngineConfig, WindowOutput
from streamfix.streaming.offline import clean_motion


def _smooth_motion(T=200, J=5, seed=0) -> np.ndarray:
    """Sums of sines with random phases: a smooth (T, J, 3) path in metres."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None]
    f = rng.uniform(0.02, 0.08, (1, J, 3))
    return 0.3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6, (1, J, 3))) + rng.normal(0, 1, (1, J, 3))


def test_debiasing_removes_a_known_offset():
    ref = _smooth_motion()
    rng = np.random.default_rng(1)
    offset = rng.normal(0, 0.05, (1, ref.shape[1], 3))
    noise = rng.normal(0, 0.002, ref.shape)
    pred = ref + offset + noise
    ref[5:9, 2] = np.nan  # missing reference samples do not disturb the mean offset
    raw = np.nanmean(np.linalg.norm(pred - ref, axis=2))
    deb = np.nanmean(np.linalg.norm(remove_mean_offset(pred, ref) - ref, axis=2))
    assert raw > 0.04 and deb < 0.005
    np.testing.assert_allclose((remove_mean_offset(pred, ref) - pred)[0], -np.nanmean(pred - ref, axis=0))


@pytest.mark.parametrize("delay", [3, -2, 0])
def test_lag_finds_a_known_delay(delay):
    ref = _smooth_motion(T=240, seed=2)
    pred = np.roll(ref, delay, axis=0)  # pred(t) = ref(t - delay): late by `delay` frames
    pred[: max(delay, 0)] = np.nan
    if delay < 0:
        pred[delay:] = np.nan
    lags, corr = velocity_xcorr(pred, ref, max_lag=8)
    assert lags[np.nanargmax(corr)] == delay
    assert np.nanmax(corr) == pytest.approx(1.0)


def test_slow_error_keeps_slow_drift_and_drops_fast_jitter_and_offset():
    """A constant offset (debiased away), a 0.5 Hz drift (kept) and 10 Hz jitter (removed) at 30 Hz."""
    ref = _smooth_motion(T=300, J=4)
    t = np.arange(300)[:, None, None] / 30.0
    drift = 0.02 * np.sin(2 * np.pi * 0.5 * t) * np.array([1.0, 0.0, 0.0])
    jitter = 0.02 * np.sin(2 * np.pi * 10.0 * t) * np.array([0.0, 1.0, 0.0])
    pred = ref + 0.1 + drift + jitter
    pred[40:45, 1] = np.nan  # a gap: NaN out, neighbours unaffected
    slow = slow_error_norm(pred, ref, 30.0)
    assert np.isnan(slow[40:45, 1]).all() and np.isfinite(slow[:40]).all()
    inner = slow[30:-30, 0]  # away from the filter's ends
    np.testing.assert_allclose(inner, np.abs(drift[30:-30, 0, 0]), atol=0.002)
    # without the drift nothing slow is left: the jitter is above the cut-off
    assert np.nanmax(slow_error_norm(ref + 0.1 + jitter, ref, 30.0)[30:-30]) < 0.002


def test_second_difference_is_zero_on_a_line_and_nan_at_the_ends():
    x = np.linspace(0, 1, 20)[:, None, None] * np.array([1.0, 2.0, 3.0])
    d2 = second_difference_norm(np.repeat(x, 2, axis=1))
    assert np.isnan(d2[[0, -1]]).all() and np.allclose(d2[1:-1], 0.0)


def test_rigid_fits_recover_a_known_transform():
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    A = q * np.sign(np.linalg.det(q))  # a rotation
    b = np.array([0.3, -1.0, 2.5])
    # bodies with known offsets: y = A (R o + p) + b, plus one gross outlier
    T, K = 120, 4
    Rb = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(T * K)]).reshape(T, K, 3, 3)
    Rb *= np.sign(np.linalg.det(Rb))[..., None, None]
    p = rng.normal(0, 1, (T, K, 3))  # body positions
    o = rng.normal(0, 0.08, (K, 3))
    y = (p + np.einsum("tkij,kj->tki", Rb, o)) @ A.T + b
    A1, b1 = fit_rigid(p.reshape(-1, 3) + np.einsum("tkij,kj->tki", Rb, o).reshape(-1, 3), y.reshape(-1, 3))
    np.testing.assert_allclose(A1, A, atol=1e-9)
    np.testing.assert_allclose(b1, b, atol=1e-9)
    y[7, 1, 0] += 1.0  # a hand 1 m off for one frame
    fit = fit_rigid_with_offsets(y, Rb, p)
    np.testing.assert_allclose(fit.rotation, A, atol=1e-6)
    np.testing.assert_allclose(fit.offsets, o, atol=1e-6)
    assert not fit.inliers[7, 1] and fit.inliers.sum() == T * K - 1
    assert fit.residuals[7, 1] == pytest.approx(1.0, abs=1e-6)


def test_reference_scored_against_itself():
    """Jitter ratio 1, no error, no lag, when the 'sensor' is the reference itself."""
    take = load_take(next(r for r in find_takes(limit=3) if r.dataset == "uiprmd"))
    ref = take.reference
    sensor = np.where(np.isfinite(ref), ref, take.sensor.positions)
    same = PairedTake("uiprmd", take.key, take.subject, take.movement, True,
                      Motion.from_positions(sensor, take.sensor.skeleton, take.sensor.rate_hz), ref)
    recs = aggregate([("uiprmd", score_take(same, ["input"]))])
    assert {r["region"] for r in recs} == {"all", "upper", "lower"}
    for r in recs:
        assert r["jitter_ratio"] == pytest.approx(1.0)
        assert r["mean_error_m"] == 0.0 and r["debiased_mean_m"] < 1e-9
        assert r["lag_frames"] == 0 and r["n_takes"] == 1


def test_regions_by_joint_name():
    assert [body_region(n) for n in ("LKnee", "HipRight", "Waist", "SpineBase", "FootLeft")] == ["lower"] * 5
    assert [body_region(n) for n in ("HeadTip", "Neck", "RWrist", "HandLeft", "SpineShoulder")] == ["upper"] * 5


@pytest.mark.parametrize("method", ["streamfix_serve", "streamfix"])
def test_handover_frames_are_where_the_engine_blend_passes_to_a_newer_window(method):
    """Run the real engine, on the schedule ``method`` runs, with a window solver whose
    answer is the index of the window (every joint, every frame): the clean output of a
    frame is then the blend's weighted mean of window indices, nearest to the window that
    dominates it. The hand-over frames are where that window changes, and the frame before."""
    from streamfix.evaluation.registry import engine_config
    from streamfix.motion import Motion
    from streamfix.skeletons import KINECT_V2

    cfg = engine_config(method, 30.0)
    T = cfg.window + cfg.lookahead + 5 * cfg.hop  # at least four hand-overs on either schedule
    m = Motion(np.zeros((T, 25, 3)), np.ones((T, 25)), np.arange(T) / 30.0, 30.0, KINECT_V2)
    count = [0]

    def solver(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None, **kw):
        count[0] += 1
        return WindowOutput(np.full(np.shape(positions), float(count[0])), np.zeros(np.shape(positions)[:2], dtype=bool))

    out, _ = clean_motion(m, cfg, window_solver=solver)
    y = out.positions[:, 0, 0]
    # a frame blended from two windows is nearer the one with the larger weight (an even
    # split, 0.5 away from both, goes to the older window, as the blend's first maximum)
    dominant = np.ceil(y - 0.5 - 1e-9)
    n_last = T - cfg.lookahead - 1  # the flush window at the end is not on the schedule
    switch = np.flatnonzero(np.diff(dominant[:n_last]) > 0) + 1
    expected = np.zeros(T, dtype=bool)
    expected[switch] = expected[switch - 1] = True
    got = handover_frames(T, 30.0, method)
    assert len(switch) >= 4
    assert np.array_equal(got[:n_last - 1], expected[:n_last - 1])


def test_move_scaled_to_the_bar_shrinks_only_the_tracked_move():
    from streamfix.core.metrics import mean_move
    from streamfix.evaluation.paired import move_scaled_to

    rng = np.random.default_rng(3)
    x = rng.normal(size=(40, 4, 3))
    y = x + rng.normal(scale=0.02, size=x.shape)
    tracked = np.ones((40, 4), dtype=bool)
    tracked[:, 3] = False  # an untracked joint keeps the output's value
    now = mean_move(y, x, tracked)
    capped, a = move_scaled_to(y, x, tracked, 0.5 * now)
    assert a == pytest.approx(0.5) and mean_move(capped, x, tracked) == pytest.approx(0.5 * now)
    np.testing.assert_allclose(capped[:, 3], y[:, 3])
    np.testing.assert_allclose(capped[:, :3], x[:, :3] + 0.5 * (y[:, :3] - x[:, :3]))
    same, a = move_scaled_to(y, x, tracked, 2 * now)  # already within: unchanged
    assert a == 1.0 and same is y
