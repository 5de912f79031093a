"""`streamfix eval --protocol occlusion`: the paper's whole-window joint dropping on a held-out take."""
from __future__ import annotations

import math

import numpy as np

from streamfix.evaluation.occlusion import PROTOCOLS, drop_masks, nearest_joint_fill


def test_drop_masks_drop_whole_windows():
    rng = np.random.default_rng(0)
    keep = drop_masks(3, 25, 64, "random", 50, rng)
    per_window = (~keep).all(axis=1)  # a dropped joint is gone for the whole window
    assert np.array_equal((~keep).any(axis=1), per_window)
    assert list(per_window.sum(axis=1)) == [12, 12, 12]  # round(0.5 * 25) joints
    assert len({tuple(np.flatnonzero(p)) for p in per_window}) > 1  # a new subset per window
    arm = drop_masks(1, 25, 8, "right_arm", 24, rng)
    assert sorted(np.flatnonzero(~arm[0, 0])) == [8, 9, 10, 11, 23, 24]


def test_nearest_joint_baseline_copies_a_neighbour():
    pos = np.random.default_rng(1).normal(size=(10, 25, 3))
    obs = np.ones((10, 25), bool)
    obs[:, 11] = False  # HandRight -> nearest seen along the bones: WristRight (10)
    obs[3:6, 4] = False  # a short gap is interpolated in time instead
    out = nearest_joint_fill(pos, obs, np.array([[0, 1], [10, 11], [10, 24], [11, 23], [9, 10]]))
    np.testing.assert_array_equal(out[:, 11], pos[:, 10])
    np.testing.assert_allclose(out[4, 4], pos[2, 4] + (pos[6, 4] - pos[2, 4]) * 0.5)
    np.testing.assert_array_equal(out[obs], pos[obs])


def test_protocol_records_on_a_held_out_kinect_take(shared_data):
    methods = ["nearest_joint", "prior_encode", "prior_latent"]
    recs = PROTOCOLS["occlusion"](
        [shared_data / "kinect_v2" / "Ges04_comehere.csv"], rate_hz=30.0, levels=[50], seed=1, methods=methods
    )
    keys = {"file", "rate_hz", "protocol", "level", "method", "aje_m", "abe_m", "jitter", "rmse_m"}
    assert all(keys <= set(r) for r in recs)
    assert {r["method"] for r in recs} == set(methods)
    assert {(r["pattern"], round(r["level"])) for r in recs} == {
        ("random", 50), ("right_arm", 24), ("left_arm", 24), ("right_leg", 16), ("left_leg", 16)
    }
    for r in recs:
        assert r["protocol"] == "occlusion" and math.isfinite(r["rmse_m"]) and r["rmse_m"] >= 0
        # rmse over all joints includes the observed (kept exactly) ones, so it is below the dropped-only RMSE
        assert r["rmse_m"] <= r["rmse_dropped_m"] + 1e-12
    again = PROTOCOLS["occlusion"](
        [shared_data / "kinect_v2" / "Ges04_comehere.csv"], rate_hz=30.0, levels=[50], seed=1, methods=methods
    )
    assert [r["rmse_m"] for r in again] == [r["rmse_m"] for r in recs]  # seeded
