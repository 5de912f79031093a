"""Inferred limbs that the rest of the body contradicts give way to the prior's fill
(core/inferred.py, BridgingWindowSolver(verify_inferred=True)): a limb the sensor froze
in its last pose while the person walked on, flagged inferred, on real mocap. Off by
default: the same arm flagged inferred but *correct* is moved several cm toward the
prior's fill, whose error on a swinging arm is larger than the check's threshold."""
from __future__ import annotations

import numpy as np

from streamfix.core.inferred import replacement_weight, tracked_proximity
from streamfix.motion import Motion
from streamfix.skeletons import get_skeleton
from streamfix.streaming.bridging import BridgingWindowSolver
from streamfix.streaming.engine import EngineConfig
from streamfix.streaming.offline import clean_motion
from test_frozen_limbs import walk_with_failed_arm

KV2 = get_skeleton("kinect_v2")
RATE = 30.0


def test_tracked_proximity_fades_with_time_from_a_tracked_sample():
    trk = np.zeros((200, 2), dtype=bool)
    trk[50, 0] = True
    g = tracked_proximity(trk, RATE, (1.0, 2.0))
    assert g[50, 0] == 1.0 and g[50 + 30, 0] == 1.0 and g[50 - 30, 0] == 1.0
    assert g[50 + 60, 0] == 0.0 and 0.0 < g[50 + 45, 0] < 1.0
    assert (g[:, 1] == 0).all()  # never tracked: never questioned


def test_replacement_weight_keeps_agreeing_samples_and_shares_a_limb():
    T = 40
    fill = np.zeros((T, 3, 3))
    x = fill.copy()
    x[20:, 2, 0] = 0.5            # joint 2 parts from the fill by 50 cm from frame 20 on
    x[:, 1, 0] = 0.03             # joint 1 stays 3 cm from it
    cand = np.ones((T, 3), dtype=bool)
    w = replacement_weight(x, fill, cand, cand, span=1)
    assert (w[:, 1] == 0).all() and (w[:20, 2] == 0).all() and (w[25:, 2] == 1).all()
    shared = replacement_weight(x, fill, cand, cand, [np.array([1, 2])], span=1)
    assert (shared[25:, 1] == 1).all()  # a limb fails as one piece
    assert (replacement_weight(x, fill, cand, np.zeros_like(cand)) == 0).all()


def test_a_frozen_inferred_arm_on_a_walking_body_is_pulled_toward_the_truth(shared_data):
    truth, x, conf, arm, a, b = walk_with_failed_arm(shared_data, a=60, b=105)  # 1.5 s, after 2 s of history
    motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
    cfg = EngineConfig(rate_hz=RATE)
    # without the frozen-limb release (on by default, tests/test_frozen_limbs.py), which frees this arm itself
    out, _ = clean_motion(motion, cfg, BridgingWindowSolver(verify_inferred=True, release_frozen=False))
    off, _ = clean_motion(motion, cfg, BridgingWindowSolver(release_frozen=False))  # inferred samples left to the window pipeline

    def err(y):
        return float(np.linalg.norm(y[a:b, arm] - truth[a:b, arm], axis=2).mean())

    e_in, e_out, e_off = err(x), err(out.positions), err(off.positions)
    print(f"frozen arm 1.5 s: input {e_in * 1000:.0f} mm, output {e_out * 1000:.0f}, unchecked {e_off * 1000:.0f}")
    assert e_out < 0.95 * min(e_in, e_off)
    assert out.recovered[a + 15:b, arm].any()  # what was replaced is flagged recovered
    # joints the sensor tracked are not touched by the check
    rest = np.setdiff1d(np.arange(25), arm)
    assert np.abs(out.positions[:, rest] - off.positions[:, rest]).max() < 0.05
