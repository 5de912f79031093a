"""The body's net travel speed, which frees the prior's arm fills while walking."""
from __future__ import annotations

import numpy as np

from streamfix.core.excursion import travel_speed

RATE = 30.0


def _body(n_frames: int, velocity: np.ndarray, seed: int = 0) -> np.ndarray:
    """A 10-joint body (m) translating at ``velocity`` (m/s) with two limbs swinging 30 cm at 1 Hz."""
    rng = np.random.default_rng(seed)
    pose = rng.normal(0.0, 0.3, (10, 3))
    t = np.arange(n_frames) / RATE
    x = pose[None] + t[:, None, None] * velocity[None, None, :]
    swing = 0.3 * np.sin(2 * np.pi * t)[:, None]
    x[:, 8, 0] += swing[:, 0]
    x[:, 9, 0] -= swing[:, 0]
    return x


def test_a_walking_body_travels_at_its_speed_and_a_body_in_place_does_not():
    walk = _body(91, np.array([1.2, 0.0, 0.0]))
    still = _body(91, np.zeros(3))
    obs = np.ones(walk.shape[:2], dtype=bool)
    assert abs(travel_speed(walk, obs, RATE) - 1.2) < 0.01
    assert travel_speed(still, obs, RATE) < 0.01  # limbs swing a whole period: no travel


def test_missing_joints_and_frames_are_ignored():
    x = _body(91, np.array([0.0, 0.0, 0.8]))
    obs = np.ones(x.shape[:2], dtype=bool)
    obs[:10] = False           # the span starts at the first observed frame
    obs[50:, :3] = False       # joints lost later do not move the estimate
    x[~obs] = np.nan
    assert abs(travel_speed(x, obs, RATE) - 0.8) < 0.01
    assert travel_speed(x[:1], obs[:1], RATE) == 0.0
    assert travel_speed(x, np.zeros_like(obs), RATE) == 0.0
