"""The live topic's One Euro filter smooths as much as the window solver finds sensor noise."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import kernels
from streamfix.core.metrics import jitter
from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.engine import EngineConfig, StreamEngine
from streamfix.streaming.live import LiveConfig, LivePath
from streamfix.streaming.solver_api import WindowOutput


@pytest.fixture(scope="module")
def walking(walking_kinect30):
    return walking_kinect30[:300]


def _run_path(x: np.ndarray, config: LiveConfig, share: float | None) -> np.ndarray:
    live = LivePath(x.shape[1], KINECT_V2.bone_array, 30.0, config)
    if share is not None:
        live.set_noise_share(share)
    valid = np.ones(x.shape[1], dtype=bool)
    return np.array([live.step(x[i], valid, i / 30.0)[0] for i in range(len(x))])


@pytest.mark.parametrize("compiled", [True, False])
def test_the_share_sets_the_resting_cutoff(walking, monkeypatch, compiled):
    """Share 1 is the configured filter, 0.5 a doubled resting cutoff, 0 no filter at all (the
    gated samples as they are), bit for bit on the compiled chain and its numpy reference;
    ``match_noise=False`` ignores the share."""
    if not compiled:
        monkeypatch.setattr(kernels, "COMPILED", False)
    x = walking + np.random.default_rng(2).normal(0.0, 0.004, walking.shape)
    default = _run_path(x, LiveConfig(), None)
    assert np.array_equal(_run_path(x, LiveConfig(), 1.0), default)
    assert np.array_equal(_run_path(x, LiveConfig(), 0.5), _run_path(x, LiveConfig(min_cutoff=6.0), None))
    assert np.array_equal(_run_path(x, LiveConfig(), 0.0), _run_path(x, LiveConfig(filter="none"), None))
    assert np.array_equal(_run_path(x, LiveConfig(match_noise=False), 0.0), default)
    assert np.array_equal(_run_path(x, LiveConfig(), float("nan")), default)  # no verdict: smooth
    assert not np.array_equal(_run_path(x, LiveConfig(), 0.0), default)  # the case occurs


def _live_topic(x: np.ndarray, confidence: np.ndarray, skeleton, live: LiveConfig, solver=None) -> np.ndarray:
    engine = StreamEngine(skeleton, EngineConfig(rate_hz=30.0, live=live), solver)
    out = []
    for i in range(len(x)):
        frame = SkeletonFrame("s", i, int(round(i / 30.0 * 1e9)), skeleton.name, [BodyFrame(0, x[i], confidence[i])])
        out += [f.bodies[0].positions for k, f in engine.push(frame) if k == "live"]
    engine.flush()
    return np.array(out)


def test_exact_motion_capture_reaches_the_live_topic_without_the_filters_lag(walking):
    """Every window of exact mocap reports no sensor noise: after the first one the live topic
    is the samples themselves (the One Euro filter had left them 12 mm behind on average)."""
    conf = np.ones(walking.shape[:2])
    moved = {}
    for match in (True, False):
        live = _live_topic(walking, conf, KINECT_V2, LiveConfig(match_noise=match))
        assert live.shape == walking.shape
        moved[match] = np.linalg.norm(live[90:] - walking[90:], axis=2).mean()  # after the first window
    assert moved[True] < 1e-3
    assert moved[False] > 8e-3


def test_a_kinect_recording_keeps_its_smoothing(shared_data):
    """A real Kinect v2 recording is noisy in every window: the live topic is smoothed as before."""
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    x, conf = m.positions, m.confidence  # 154 frames
    on = _live_topic(x, conf, m.skeleton, LiveConfig())
    off = _live_topic(x, conf, m.skeleton, LiveConfig(match_noise=False))
    assert jitter(on) <= 1.02 * jitter(off)
    assert jitter(on) < 0.7 * jitter(np.where(np.isfinite(x), x, on))  # still smoothed (0.52x the input's)


def test_a_solver_that_reports_no_noise_share_leaves_the_filter_as_configured(walking):
    """The share is the solver's statement; a solver that makes none (a user's own) does not
    switch the live filter off."""
    def passthrough(positions, confidence, bones, bone_lengths, rate_hz, config=None, state=None, init=None):
        return WindowOutput(np.asarray(positions, dtype=np.float64), np.zeros(np.shape(confidence), dtype=bool))

    conf = np.ones(walking.shape[:2])
    on = _live_topic(walking, conf, KINECT_V2, LiveConfig(), passthrough)
    off = _live_topic(walking, conf, KINECT_V2, LiveConfig(match_noise=False), passthrough)
    assert np.array_equal(on, off)
