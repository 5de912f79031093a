"""The least move that meets the jitter and bone-CV bars (streamfix.core.least_move): its terms are
the metrics' own, its gradients exact, and what it finds meets both bars moving less than the
outputs we know meet them."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import metrics
from streamfix.core.least_move import bar_terms, least_move_meeting_bars
from streamfix.io import read_motion

CHAIN = np.array([[0, 1], [1, 2], [2, 3], [1, 4]])


def _chain_motion(n_frames: int = 60, seed: int = 0, noise_m: float = 0.004):
    """A rigid four-bone body swaying slowly (the truth) and a copy with sensor noise on every sample."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 30.0
    angle = 0.4 * np.sin(2 * np.pi * 0.5 * t)
    truth = np.zeros((n_frames, 5, 3))
    truth[:, 1] = [0.0, 0.3, 0.0]
    truth[:, 2, 0] = 0.25 * np.sin(angle)
    truth[:, 2, 1] = 0.3 + 0.25 * np.cos(angle)
    truth[:, 3] = truth[:, 2] + [0.0, 0.2, 0.0]
    truth[:, 4] = truth[:, 1] + [0.15, 0.0, 0.0]
    return truth, truth + rng.normal(scale=noise_m, size=truth.shape)


def test_the_terms_are_the_metrics_and_the_gradients_exact():
    rng = np.random.default_rng(1)
    _, x = _chain_motion(14)
    y = x + rng.normal(scale=0.01, size=x.shape)
    counted = rng.random(x.shape[:2]) > 0.3
    observed = rng.random(x.shape[:2]) > 0.1
    (move, jit, cv), grads = bar_terms(y, x, counted, observed, CHAIN)
    y_obs = np.where(observed[..., None], y, np.nan)
    assert jit == pytest.approx(metrics.jitter(y_obs), rel=1e-6)
    assert cv == pytest.approx(metrics.bone_length_cv(y_obs, CHAIN), rel=1e-6)
    assert move == pytest.approx(np.linalg.norm(y - x, axis=2)[counted & observed].mean(), rel=1e-6)
    h = 1e-6
    for k in range(3):
        for _ in range(6):
            idx = tuple(int(rng.integers(0, s)) for s in y.shape)
            up, down = y.copy(), y.copy()
            up[idx] += h
            down[idx] -= h
            numeric = (bar_terms(up, x, counted, observed, CHAIN, False)[k]
                       - bar_terms(down, x, counted, observed, CHAIN, False)[k]) / (2 * h)
            assert grads[k][idx] == pytest.approx(numeric, rel=1e-4, abs=1e-7)


def test_it_meets_both_bars_moving_no_more_than_the_truth_does():
    truth, x = _chain_motion()
    everyone = np.ones(x.shape[:2], dtype=bool)
    cv_max = 0.1 * metrics.bone_length_cv(x, CHAIN)
    jitter_max = 1.05 * metrics.jitter(truth)  # the rigid, smooth truth meets both bars
    assert metrics.bone_length_cv(truth, CHAIN) <= cv_max and metrics.jitter(x) > 3 * jitter_max
    found = least_move_meeting_bars(x, everyone, everyone, CHAIN, jitter_max, cv_max, steps=4000)
    assert found.feasible
    assert found.jitter <= jitter_max and found.bone_cv <= cv_max
    truth_move = np.linalg.norm(truth - x, axis=2).mean()
    assert 0 < found.move_m <= truth_move
    # an input that already meets its bars is left where it is
    still = least_move_meeting_bars(truth, everyone, everyone, CHAIN, 2 * metrics.jitter(truth), 1.0, steps=500)
    assert still.feasible and still.move_m < 1e-4


def test_on_a_real_kinect_take_it_moves_less_than_the_engine(shared_data):
    from streamfix.evaluation.registry import run_method

    m = read_motion(shared_data / "kinect_v2" / "Ges04_comehere.csv")
    x, conf, bones = m.positions, m.confidence, m.skeleton.bone_array
    observed = np.isfinite(x).all(axis=2) & (conf > 0)
    tracked = observed & (conf >= 1.0)
    smooth = run_method("median_savgol", x, conf, bones, m.rate_hz, skeleton=m.skeleton)
    engine = run_method("streamfix", x, conf, bones, m.rate_hz, skeleton=m.skeleton)
    jitter_max = metrics.jitter(np.where(observed[..., None], smooth, np.nan))
    cv_max = 0.1 * metrics.bone_length_cv(x, bones)
    engine_obs = np.where(observed[..., None], engine, np.nan)
    assert metrics.jitter(engine_obs) <= jitter_max and metrics.bone_length_cv(engine_obs, bones) <= cv_max
    found = least_move_meeting_bars(x, tracked, observed, bones, jitter_max, cv_max, start=smooth, steps=3000)
    assert found.feasible
    engine_move = np.linalg.norm(engine - x, axis=2)[tracked].mean()
    assert found.move_m < 0.8 * engine_move


def test_bad_arguments_are_named():
    _, x = _chain_motion(10)
    everyone = np.ones(x.shape[:2], dtype=bool)
    with pytest.raises(ValueError, match="observed must be"):
        least_move_meeting_bars(x, everyone, everyone[:, :3], CHAIN, 1.0, 1.0)
    with pytest.raises(ValueError, match="positive"):
        least_move_meeting_bars(x, everyone, everyone, CHAIN, 0.0, 1.0)
    with pytest.raises(ValueError, match=r"\(T, J, 3\)"):
        least_move_meeting_bars(x[..., :2], everyone, everyone, CHAIN, 1.0, 1.0)
