"""``serve``'s clean output smooths the model's fills over a wider span than measurements.

A joint the sensor lost (or placed decimetres off) is filled by each window; the fill's
frame-to-frame change is where one window hands over to the next, not motion. On UI-PRMD
the output jitter of ``serve`` was mostly such fills (the legs Kinect v1 loses), so fills
get the ``fill_smooth_s`` kernel while tracked joints keep the narrow one.
"""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.evaluation.sensor import ground_truth
from streamfix.motion import Motion
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.engine import EngineConfig
from streamfix.streaming.offline import clean_motion

RATE = 30.0
ARM_R = [KINECT_V2.joint_names.index(n + "Right") for n in ("Elbow", "Wrist", "Hand", "HandTip", "Thumb")]
LOST = slice(150, 240)  # 3 s without the right arm


@pytest.fixture(scope="module")
def runs(shared_data):
    """CMU 131_01 (walking) as Kinect v2 at 30 Hz with 1 cm sensor noise on every sample and
    the right arm lost for 3 s, cleaned on ``serve``'s schedule with and without fill smoothing."""
    truth = ground_truth(str(shared_data / "cmu_bvh" / "131_01.bvh"), RATE).positions[:300]
    noisy = truth + np.random.default_rng(0).normal(0.0, 0.01, truth.shape)
    noisy[LOST, ARM_R] = np.nan
    conf = np.where(np.isfinite(noisy).all(axis=2), 1.0, 0.0)
    motion = Motion(noisy, conf, np.arange(len(noisy)) / RATE, RATE, KINECT_V2)
    out = {}
    for label, cfg in (("on", EngineConfig(rate_hz=RATE)),
                       ("off", EngineConfig(rate_hz=RATE, fill_smooth_s=EngineConfig().output_smooth_s))):
        out[label] = clean_motion(motion, cfg)[0].positions
    return truth, out


def _jitter(x: np.ndarray) -> float:
    """Mean second difference (m/frame^2) of ``(T, J, 3)`` positions."""
    return float(np.linalg.norm(np.diff(x, n=2, axis=0), axis=2).mean())


def test_fills_are_smoother_and_no_worse(runs):
    truth, out = runs
    fill_on, fill_off = out["on"][LOST, ARM_R], out["off"][LOST, ARM_R]
    assert np.isfinite(fill_on).all()
    # the arm's own swing is in both (the truth's second difference is larger than either fill's)
    # measured 0.97x with the shipped prior, whose fills already hand over steadily (0.92x with the
    # 300-epoch prior before it, 0.86x beside a 1-frame output kernel); without fill smoothing: 1.0x
    assert _jitter(fill_on) < 0.985 * _jitter(fill_off)
    err_on = np.linalg.norm(fill_on - truth[LOST, ARM_R], axis=2).mean()
    err_off = np.linalg.norm(fill_off - truth[LOST, ARM_R], axis=2).mean()
    assert err_on <= err_off  # measured 59.7 vs 59.8 mm


def test_tracked_joints_keep_the_narrow_kernel(runs):
    _, out = runs
    others = [j for j in range(KINECT_V2.n_joints) if j not in ARM_R]
    # the clean bone lengths the next windows start from see the smoother arm, and a discrete decision
    # downstream (a foot's support) may flip on a frame or two: sub-millimetre on all but a few samples
    # (measured 0.04 % of them; the wider kernel on every joint moves 20 % by more than 1 mm)
    moved = np.linalg.norm(out["on"][:, others] - out["off"][:, others], axis=2)
    assert (moved > 1e-3).mean() < 0.01
    assert np.median(moved) < 1e-4


def test_fill_kernel_is_at_least_the_output_kernel():
    with pytest.raises(ValueError, match="fill_smooth_s"):
        EngineConfig(output_smooth_s=0.1, fill_smooth_s=0.05)
