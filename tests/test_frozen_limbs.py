"""Inferred limbs that stopped bending are the sensor's guess, and the default engine
replaces them (core/frozen.py, BridgingWindowSolver(release_frozen=True)): the measure
against a least-squares reference, the decision on made-up limbs, and the engine's clean
output on real mocap with an arm frozen or drifting while flagged inferred, the same arm
flagged inferred but right, and a real Kinect v2 recording whose legs are inferred for
eleven seconds."""
from __future__ import annotations

import numpy as np

from streamfix.core.frozen import MIN_DECIDING_BONE_M, articulation, frozen_inferred
from streamfix.motion import CONFIDENCE_INFERRED, Motion
from streamfix.skeletons import get_skeleton
from streamfix.streaming.bridging import BridgingWindowSolver
from streamfix.streaming.engine import EngineConfig
from streamfix.streaming.offline import clean_motion

KV2 = get_skeleton("kinect_v2")
RATE = 30.0


def _reference_articulation(x: np.ndarray, parents: np.ndarray, span: int) -> np.ndarray:
    """Loop-by-loop reference: a least-squares line per joint and axis over the span
    (clipped at the ends by repeating the end frames, as uniform_filter1d's 'nearest')."""
    T, J = x.shape[:2]
    h = span // 2
    out = np.full((T, J), np.nan)
    for t in range(T):
        idx = np.clip(np.arange(t - h, t - h + span), 0, T - 1)
        tt = np.arange(t - h, t - h + span, dtype=float)
        tt = np.where(np.arange(t - h, t - h + span) < 0, 0, tt)
        tt = np.where(np.arange(t - h, t - h + span) > T - 1, T - 1, tt)
        for j in range(J):
            if parents[j] < 0:
                continue
            rel = x[idx, j] - x[idx, parents[j]]
            A = np.stack([tt, np.ones_like(tt)], axis=1)
            coef, *_ = np.linalg.lstsq(A, rel, rcond=None)
            out[t, j] = np.sqrt(((rel - A @ coef) ** 2).mean(axis=0).sum())
    return out


def test_articulation_matches_a_least_squares_reference_and_is_zero_for_lines():
    rng = np.random.default_rng(3)
    T, span = 40, 9
    parents = np.array([-1, 0, 1, 2])
    x = rng.normal(size=(T, 4, 3)) * 0.05
    t = np.arange(T, dtype=float)[:, None]
    x[:, 2] = x[:, 1] + np.array([0.3, 0.0, 0.0])  # frozen relative to its parent
    x[:, 3] = x[:, 2] + 0.01 * t * np.array([1.0, -2.0, 0.5])  # drifting at a constant velocity
    got = articulation(x, parents, span)
    ref = _reference_articulation(x, parents, span)
    assert np.isnan(got[:, 0]).all()  # the root has no parent
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], atol=1e-7)
    assert np.abs(got[:, 2:]).max() < 1e-6  # frozen and drifting limbs follow a line
    assert got[:, 1].min() > 0.01  # a noisy joint does not
    x[20, 1] = np.nan
    assert np.isnan(articulation(x, parents, span)[16:25, 1]).all()  # NaN poisons the frames that see it


def _arm_layout():
    """Shoulder (root) -> elbow -> wrist -> hand: a 0.3 m upper arm, 0.25 m forearm, 0.08 m hand."""
    return np.array([-1, 0, 1, 2]), np.array([False, True, True, True])


def _arm(T: int, bend_hz: float = 0.5) -> np.ndarray:
    t = np.arange(T) / RATE
    ang = 0.8 * np.sin(2 * np.pi * bend_hz * t)
    x = np.zeros((T, 4, 3))
    x[:, 1] = x[:, 0] + np.stack([0.3 * np.cos(ang), 0.3 * np.sin(ang), 0 * t], axis=1)
    x[:, 2] = x[:, 1] + np.stack([0.25 * np.cos(2 * ang), 0.25 * np.sin(2 * ang), 0 * t], axis=1)
    x[:, 3] = x[:, 2] + np.stack([0.08 * np.cos(2 * ang), 0.08 * np.sin(2 * ang), 0 * t], axis=1)
    return x


def test_frozen_inferred_marks_a_frozen_limb_and_spares_a_bending_one():
    parents, limbs = _arm_layout()
    T = 90
    x = _arm(T)
    inferred = np.zeros((T, 4), dtype=bool)
    inferred[30:75, 1:] = True
    # bending while flagged inferred: the sensor's guess is right, nothing is frozen
    assert not frozen_inferred(x, inferred, parents, limbs, RATE).any()
    # the elbow-down part keeps its pose relative to the shoulder from frame 30 on
    frozen = x.copy()
    frozen[30:75, 1:] = x[29, 1:][None]
    got = frozen_inferred(frozen, inferred, parents, limbs, RATE)
    assert got[30:75, 1:].all() and not got[:30].any() and not got[75:].any()
    # drifting at a constant velocity is the same guess
    drift = frozen.copy()
    drift[30:75, 1:] += (0.06 / RATE) * np.arange(45)[:, None, None] * np.array([0.0, 0.6, 0.8])
    assert frozen_inferred(drift, inferred, parents, limbs, RATE)[30:75, 1:].all()
    # a run shorter than MIN_FROZEN_S is a pause, not a guess
    short = inferred.copy()
    short[44:75] = False  # 14 frames
    assert not frozen_inferred(frozen, short, parents, limbs, RATE).any()
    # tracked samples are never frozen, however still
    assert not frozen_inferred(frozen, np.zeros_like(inferred), parents, limbs, RATE).any()


def _two_arms(T: int):
    """Both arms of ``_arm`` on one root: joints 0 root, 1-3 left elbow/wrist/hand,
    4-6 right; the right arm swings half a period behind."""
    left = _arm(T)
    right = np.roll(_arm(T + 30), -15, axis=0)[:T]
    x = np.concatenate([left, right[:, 1:]], axis=1)
    parents = np.array([-1, 0, 1, 2, 0, 4, 5])
    limbs = np.array([False, True, True, True, True, True, True])
    mirror = np.array([0, 4, 5, 6, 1, 2, 3])
    return x, parents, limbs, mirror


def _left_arm_frozen(T: int = 90):
    """``_two_arms`` with the left arm flagged inferred over frames 30-74 and frozen there
    in its frame-29 pose; returns (true positions, frozen positions, inferred, parents,
    limbs, mirror)."""
    x, parents, limbs, mirror = _two_arms(T)
    inferred = np.zeros((T, 7), dtype=bool)
    inferred[30:75, 1:4] = True
    frozen = x.copy()
    frozen[30:75, 1:4] = x[29, 1:4][None]  # the left arm stops bending
    return x, frozen, inferred, parents, limbs, mirror


def test_a_rigid_limb_beside_a_still_twin_is_a_person_holding_still():
    x, frozen, inferred, parents, limbs, mirror = _left_arm_frozen()
    # the right arm swings on: the left one is the sensor's guess
    assert frozen_inferred(frozen, inferred, parents, limbs, RATE, mirror=mirror)[30:75, 1:4].all()
    # the right arm is still too: the person holds both still
    still = frozen.copy()
    still[:, 4:] = x[29, 4:][None]
    assert not frozen_inferred(still, inferred, parents, limbs, RATE, mirror=mirror).any()
    assert frozen_inferred(still, inferred, parents, limbs, RATE)[30:75, 1:4].all()  # without the twin test


def test_a_run_little_longer_than_the_articulation_span_is_decided_on_its_interior():
    """A 17-frame freeze (0.57 s) against a 15-frame articulation span: only its 3 middle
    frames have a span wholly inside the run; the others see the arm bending before or
    after it, and a median over all of them called the frozen arm bending."""
    x, parents, limbs, mirror = _two_arms(90)
    inferred = np.zeros((90, 7), dtype=bool)
    inferred[30:47, 1:4] = True
    frozen = x.copy()
    frozen[30:47, 1:4] = x[29, 1:4][None]
    got = frozen_inferred(frozen, inferred, parents, limbs, RATE, mirror=mirror)
    assert got[30:47, 1:4].all() and not got[:, 4:].any()
    assert not frozen_inferred(x, inferred, parents, limbs, RATE, mirror=mirror).any()  # bending: not frozen


def test_a_twin_must_bend_clearly_not_just_above_the_rigid_threshold():
    """A twin articulating between RIGID_M and TWIN_BENDS_M (a leg settling after a move)
    does not make the other limb a guess: the decision would flip between overlapping
    windows as they see more or less of the settling."""
    from streamfix.core.frozen import RIGID_M, TWIN_BENDS_M, articulation

    x, frozen, inferred, parents, limbs, mirror = _left_arm_frozen()
    span = int(round(0.5 * RATE))

    def twin_with(amplitude_m: float) -> np.ndarray:
        # the right arm wobbles about its frame-29 pose: elbow about the root, wrist about the elbow
        y = frozen.copy()
        wave = amplitude_m * np.sin(2 * np.pi * 2.0 * np.arange(len(y)) / RATE)[:, None]
        y[:, 4] = y[29, 4][None] + wave * np.array([1.0, 0.0, 0.0])
        y[:, 5] = y[:, 4] + (y[29, 5] - y[29, 4])[None] + wave * np.array([0.0, 1.0, 0.0])
        y[:, 6] = y[:, 5] + (y[29, 6] - y[29, 5])[None]
        return y

    wobble = twin_with(0.012)
    med = np.median(articulation(wobble, parents, span)[30:75, 4:6], axis=0)
    assert (RIGID_M < med).all() and (med < TWIN_BENDS_M).all(), med
    assert not frozen_inferred(wobble, inferred, parents, limbs, RATE, mirror=mirror).any()
    assert frozen_inferred(wobble, inferred, parents, limbs, RATE, mirror=mirror, twin_bends_m=RIGID_M)[30:75, 1:4].all()
    swing = twin_with(0.08)
    assert (np.median(articulation(swing, parents, span)[30:75, 4:6], axis=0) > TWIN_BENDS_M).all()
    assert frozen_inferred(swing, inferred, parents, limbs, RATE, mirror=mirror)[30:75, 1:4].all()


def test_a_run_without_a_measure_is_not_frozen_and_a_missing_twin_does_not_object():
    x, frozen, inferred, parents, limbs, mirror = _left_arm_frozen()
    lost_twin = frozen.copy()
    lost_twin[:, 4:] = np.nan  # the right arm is not seen at all
    got = frozen_inferred(lost_twin, inferred, parents, limbs, RATE, mirror=mirror)
    assert got[30:75, 1:4].all()
    no_parent = frozen.copy()
    no_parent[:, 0] = np.nan  # the left elbow's articulation cannot be measured anywhere
    got = frozen_inferred(no_parent, inferred, parents, limbs, RATE, mirror=mirror)
    assert not got[:, 1].any()


def test_a_short_bone_follows_its_parent_and_does_not_decide_alone():
    parents, limbs = _arm_layout()
    T = 90
    x = _arm(T)
    assert np.linalg.norm(x[:, 3] - x[:, 2], axis=1).max() < MIN_DECIDING_BONE_M
    inferred = np.zeros((T, 4), dtype=bool)
    inferred[30:75, 3] = True
    hand_only = x.copy()
    hand_only[30:75, 3] = x[30:75, 2] + (x[29, 3] - x[29, 2])  # the hand alone stops bending
    assert not frozen_inferred(hand_only, inferred, parents, limbs, RATE).any()
    # the hand of a frozen forearm goes with it
    inferred[30:75, 2] = True
    both = x.copy()
    both[30:75, 2:] = x[30:75, 1][:, None] + (x[29, 2:] - x[29, 1])[None]
    got = frozen_inferred(both, inferred, parents, limbs, RATE)
    assert got[30:75, 2].all() and got[30:75, 3].all() and not got[:, 1].any()


# --------------------------------------------------------------------------- engine, real data
def walk_with_failed_arm(shared_data, drift_m_s: float = 0.0, move: bool = True, a: int = 90, b: int = 150):
    """CMU 131_01 (walking) as Kinect v2 joints, its left arm from the elbow down flagged
    inferred over frames [a, b) and (``move``) frozen in its pose relative to the shoulder
    (carried along by the body), drifting at ``drift_m_s``. Returns
    (truth, positions, confidence, arm joints, a, b)."""
    from streamfix.evaluation.sensor import ground_truth

    truth = ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", RATE).positions
    names = KV2.joint_names
    arm = np.array([names.index(n) for n in ("ElbowLeft", "WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft")])
    shoulder = names.index("ShoulderLeft")
    assert len(truth) > b + 30
    x = truth.copy()
    conf = np.ones(truth.shape[:2])
    if move:
        pose = truth[a - 1, arm] - truth[a - 1, shoulder]
        steps = np.arange(1, b - a + 1)[:, None, None]
        x[a:b, arm] = truth[a:b, shoulder][:, None] + pose[None] + steps * (drift_m_s / RATE) * np.array([0.0, -0.6, 0.8])
    conf[a:b, arm] = CONFIDENCE_INFERRED
    return truth, x, conf, arm, a, b


def _err(y, truth, a, b, arm) -> float:
    return float(np.linalg.norm(y[a:b, arm] - truth[a:b, arm], axis=2).mean())


def test_the_default_engine_replaces_a_frozen_or_drifting_inferred_arm(shared_data):
    cfg = EngineConfig(rate_hz=RATE)
    for drift in (0.0, 0.063):
        truth, x, conf, arm, a, b = walk_with_failed_arm(shared_data, drift)
        motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
        out, _ = clean_motion(motion, cfg)
        kept, _ = clean_motion(motion, cfg, BridgingWindowSolver(release_frozen=False))
        e_in, e_out, e_kept = (_err(y, truth, a, b, arm) for y in (x, out.positions, kept.positions))
        print(f"arm drifting {drift} m/s for 2 s: input {e_in * 1000:.0f} mm, clean {e_out * 1000:.0f}, "
              f"without the release {e_kept * 1000:.0f}")
        assert e_out < 0.8 * min(e_in, e_kept)
        assert out.recovered[a + 20:b - 10, arm].all()  # the replaced samples are flagged recovered
        rest = np.setdiff1d(np.arange(25), arm)
        assert np.abs(out.positions[:, rest] - kept.positions[:, rest]).mean() < 0.005  # the rest barely moves


def test_a_limb_frozen_for_longer_than_a_window_stays_released_to_its_end(shared_data):
    """4 s frozen, twice the window: the windows inside the run see no tracked sample of
    the arm, and before the release rode along in the solver state they handed the frozen
    pose back mid-run (the limb snapped from the fill to the guess). Both schedules."""
    a, b = 60, 180
    truth, x, conf, arm, a, b = walk_with_failed_arm(shared_data, a=a, b=b)
    motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
    for cfg in (EngineConfig(rate_hz=RATE), EngineConfig.for_files(RATE)):
        out, _ = clean_motion(motion, cfg)
        kept, _ = clean_motion(motion, cfg, BridgingWindowSolver(release_frozen=False))
        assert out.recovered[a + 20:b, arm].all()
        e_in, e_out, e_kept = (_err(y, truth, a, b, arm) for y in (x, out.positions, kept.positions))
        print(f"arm frozen 4 s (hop {cfg.hop}): input {e_in * 1000:.0f} mm, clean {e_out * 1000:.0f}, "
              f"without the release {e_kept * 1000:.0f}")
        assert e_out < 0.9 * min(e_in, e_kept)


def test_a_limb_frozen_from_a_streams_start_stays_released_while_the_windows_grow(shared_data):
    """Frozen from the second frame for 3 s: the stream's first windows grow frame by frame,
    get no warm start, and before the release memory carried across windows of different
    lengths the release ended a second in (near the one tracked sample), handing the frozen
    pose back for the rest of the run. Both schedules."""
    truth, x, conf, arm, a, b = walk_with_failed_arm(shared_data, a=91, b=181)
    truth, x, conf = truth[90:], x[90:], conf[90:]
    a, b = a - 90, b - 90
    motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
    for cfg in (EngineConfig(rate_hz=RATE), EngineConfig.for_files(RATE)):
        out, _ = clean_motion(motion, cfg)
        assert out.recovered[a + 45:b, arm].all(), cfg.hop
        assert _err(out.positions, truth, a + 45, b, arm) < 0.5 * _err(x, truth, a + 45, b, arm)


def test_an_inferred_arm_that_is_right_is_left_alone(shared_data):
    truth, x, conf, arm, a, b = walk_with_failed_arm(shared_data, move=False)
    motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
    out, _ = clean_motion(motion, EngineConfig(rate_hz=RATE))
    assert not out.recovered[a:b, arm].any()
    assert _err(out.positions, truth, a, b, arm) < 0.01


def test_a_released_arm_is_filled_free_of_the_frozen_pose_and_a_right_still_one_pays_for_it(shared_data):
    """The release's trade, measured on one input with two truths (CMU 131_01 walking, the
    left arm from the elbow down flagged inferred and rigid relative to the shoulder for 2 s,
    the right arm swinging): the sensor froze an arm that really swung, or the person held it
    still and the sensor was right. A still limb is rigid too (on the Kinect v2 recordings,
    tracked elbows, wrists, knees and ankles bend less than RIGID_M in 46-72 % of their frames),
    so both are released. Held by the excursion limit, the fill stays near its baseline, the
    frozen pose itself: the frozen arm kept three quarters of its error in ``serve`` (28 cm of
    38) and the right still arm moved 14 cm. Free of it (the default), the fill follows the
    walking body: the frozen arm is cut to about a quarter of its error and the still arm swings
    with the gait (35 cm). The sensor protocol's ``freeze`` and ``mix`` kinds score the gain over
    many takes."""
    cfg = EngineConfig(rate_hz=RATE)
    truth, x, conf, arm, a, b = walk_with_failed_arm(shared_data)
    motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
    free, _ = clean_motion(motion, cfg)
    held, _ = clean_motion(motion, cfg, BridgingWindowSolver(limit_released=True))
    assert free.recovered[a + 20:b - 10, arm].all() and held.recovered[a + 20:b - 10, arm].all()
    frozen = {name: _err(y, truth, a, b, arm) for name, y in (("input", x), ("free", free.positions),
                                                              ("held", held.positions))}
    still = {name: _err(y, x, a, b, arm) for name, y in (("free", free.positions), ("held", held.positions))}
    print(f"arm frozen while it swung: {frozen}; arm right and still: {still} (m)")
    assert frozen["free"] < 0.5 * frozen["held"] and frozen["free"] < 0.35 * frozen["input"]
    # the hazard, bounded: a right still arm ends no farther off than the frozen one raw
    assert still["free"] < frozen["input"]


def test_legs_inferred_for_long_keep_the_sensors_guess(shared_data):
    """seated_joints.csv: the knees and ankles are tracked for the first second or so, then
    inferred to the end (11 s), barely bending (a seated person's legs under a desk). Both
    legs are still, so neither is the sensor's guess of a moving limb: the release leaves
    them to the window pipeline (the output is the same as without the release). In the
    first seconds one leg settles after a move, articulating just above RIGID_M: with the
    twin test at RIGID_M the release flipped between windows there and swung the right
    knee 50 cm (TWIN_BENDS_M)."""
    from streamfix.io import read_motion

    m = read_motion(shared_data / "kinect_v2" / "seated_joints.csv")
    cfg = EngineConfig(rate_hz=m.rate_hz)
    on, _ = clean_motion(m, cfg)
    off, _ = clean_motion(m, cfg, BridgingWindowSolver(release_frozen=False))
    legs = [KV2.joint_names.index(n) for n in ("KneeLeft", "AnkleLeft", "FootLeft", "KneeRight", "AnkleRight", "FootRight")]
    inferred = (m.confidence[:, legs] > 0) & (m.confidence[:, legs] < 1)
    assert inferred.sum() > 1500
    assert not (on.recovered[:, legs] & ~off.recovered[:, legs]).any()
    assert np.abs(on.positions[:, legs] - off.positions[:, legs]).max() < 1e-3


def test_a_walking_bodys_frozen_arm_follows_the_gait_with_no_far_end_in_view(shared_data):
    """serve's 0.5 s lookahead shows no end to a 2 s freeze: the fill runs open-ended. PCA
    (the body's own walking history) and the prior fill the released arm; held within its
    recent range of the last tracked pose (the excursion limit) the fill was pulled back
    onto the frozen pose itself. While the body travels no fill is limited."""
    from streamfix.evaluation.sensor import ground_truth

    truth = ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", RATE).positions
    names = KV2.joint_names
    arm = np.array([names.index(n) for n in ("ElbowRight", "WristRight", "HandRight", "HandTipRight", "ThumbRight")])
    shoulder = names.index("ShoulderRight")
    for a, b in ((159, 224), (170, 240)):
        x = truth.copy()
        conf = np.ones(truth.shape[:2])
        x[a:b, arm] = truth[a:b, shoulder][:, None] + (truth[a - 1, arm] - truth[a - 1, shoulder])[None]
        conf[a:b, arm] = CONFIDENCE_INFERRED
        motion = Motion(x, conf, np.arange(len(x)) / RATE, RATE, KV2)
        cfg = EngineConfig(rate_hz=RATE)
        out, _ = clean_motion(motion, cfg)
        limited, _ = clean_motion(motion, cfg, BridgingWindowSolver(travel_speed_mps=None))
        e_in, e_out, e_lim = (_err(y, truth, a, b, arm) for y in (x, out.positions, limited.positions))
        print(f"right arm frozen {a}-{b}: input {e_in * 1000:.0f} mm, clean {e_out * 1000:.0f}, "
              f"limited while walking {e_lim * 1000:.0f}")
        assert out.recovered[a + 20:b, arm].all()
        assert e_out < 0.9 * e_lim and e_out < 0.75 * e_in
