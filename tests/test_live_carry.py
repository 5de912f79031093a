"""The windows' verdict carried onto the live topic (streamfix.streaming.live_carry)."""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from streamfix.evaluation.paired import remove_mean_offset
from streamfix.evaluation.sensor import _rng, ground_truth
from streamfix.motion import Motion
from streamfix.sim.sensor_errors import apply_sensor_errors
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.config import schedule_config
from streamfix.streaming.live import tree_levels
from streamfix.streaming.live_carry import CARRY_MAX_S, CARRY_MIN_M, CROSSFADE_S, WindowCarry
from streamfix.streaming.offline import clean_motion

RATE = 30.0
# a 4-joint chain 0 -> 1 -> 2 -> 3 along x, 0.3 m bones
BONES = np.array([[0, 1], [1, 2], [2, 3]])
POSE = np.array([[0.0, 0, 0], [0.3, 0, 0], [0.6, 0, 0], [0.9, 0, 0]])


def _carry() -> WindowCarry:
    return WindowCarry(tree_levels(BONES, 4), 4, RATE)


def _window_end(solved_last: np.ndarray, raw_last: np.ndarray, n: int, judged_joints: list[int]):
    """The last ``n`` frames of a window that solved ``solved_last`` where the sensor said ``raw_last``."""
    judged = np.zeros((n, 4), dtype=bool)
    judged[:, judged_joints] = True
    return (np.repeat(solved_last[None], n, 0), np.repeat(raw_last[None], n, 0), np.ones((n, 4), dtype=bool), judged)


def test_a_joint_the_window_judged_off_is_carried_from_its_parent_and_follows_it():
    carry = _carry()
    frozen = POSE.copy()
    frozen[3] += [0.0, 0.3, 0.0]  # the sensor's hand, frozen 0.3 m off where the window puts it
    live = frozen.copy()
    carry.apply(frozen, np.ones(4, dtype=bool), live, np.zeros(4, dtype=bool), 9)
    carry.take(*_window_end(POSE, frozen, carry.confirm_frames, [3]), frame=9)
    moved = live + [0.05, 0.0, 0.0]  # the body moved 5 cm; the sensor's hand stayed frozen
    moved[3] = frozen[3]
    fade = int(round(CROSSFADE_S * RATE))
    outs = [carry.apply(frozen, np.ones(4, dtype=bool), moved, np.zeros(4, dtype=bool), 10 + i) for i in range(fade + 1)]
    target = moved[2] + (POSE[3] - POSE[2])  # from its parent, as the window had it
    # the hand crossfades onto it over CROSSFADE_S, in even steps, and stays there
    steps = [np.linalg.norm(o[3] - moved[3]) for o, _ in outs]
    np.testing.assert_allclose(steps[:fade], np.linalg.norm(target - moved[3]) * np.arange(1, fade + 1) / fade)
    out, rec = outs[-1]
    np.testing.assert_allclose(out[3], target)
    np.testing.assert_array_equal(out[:3], moved[:3])
    assert rec.tolist() == [False, False, False, True]


def test_a_joint_judged_on_the_last_frame_only_is_not_carried():
    # an arm flung faster than the window's edge could follow: judged a jump on its newest frame only
    carry = _carry()
    raw = POSE.copy()
    raw[3] += [0.0, 0.2, 0.0]
    solved, raws, valid, judged = _window_end(POSE, raw, carry.confirm_frames, [])
    judged[-1, 3] = True
    carry.take(solved, raws, valid, judged, frame=5)
    assert not carry.held.any()


def test_a_joint_the_window_left_near_the_sensor_or_the_live_path_had_mended_is_not_carried():
    carry = _carry()
    near = POSE.copy()
    near[3] += [0.0, 0.5 * CARRY_MIN_M, 0.0]  # within the sensor's jitter of the window
    carry.take(*_window_end(POSE, near, carry.confirm_frames, [3]), frame=3)
    assert not carry.held.any()
    # far from the sensor, but the live path had already put it where the window does (a gated spike)
    far = POSE.copy()
    far[3] += [0.0, 0.4, 0.0]
    carry.apply(far, np.ones(4, dtype=bool), POSE.copy(), np.zeros(4, dtype=bool), 4)
    carry.take(*_window_end(POSE, far, carry.confirm_frames, [3]), frame=4)
    assert not carry.held.any()


def test_a_carried_joint_is_let_go_when_the_sensor_agrees_again_or_no_window_renews_it():
    carry = _carry()
    frozen = POSE.copy()
    frozen[3] += [0.0, 0.3, 0.0]
    valid, none = np.ones(4, dtype=bool), np.zeros(4, dtype=bool)
    fade = int(round(CROSSFADE_S * RATE))
    carry.take(*_window_end(POSE, frozen, carry.confirm_frames, [3]), frame=0)
    for i in range(fade):
        out, _ = carry.apply(frozen, valid, frozen, none, 1 + i)
    assert carry.held[3]
    np.testing.assert_allclose(out[3], POSE[3])
    # the sensor has the hand again, within CARRY_MIN_M of where it is carried: its own value from
    # then on, faded back to over CROSSFADE_S
    back = POSE + [0.0, 0.3 * CARRY_MIN_M, 0.0]
    outs = [carry.apply(back, valid, back, none, 1 + fade + i) for i in range(fade)]
    assert not carry.held.any()
    np.testing.assert_array_equal(outs[-1][0], back)
    assert not outs[-1][1].any() and outs[0][1][3]
    # a carry no window renews ends after CARRY_MAX_S (and fades out)
    frame = 1 + 2 * fade
    carry.apply(frozen, valid, frozen, none, frame)  # frozen again, and the live path shows it so
    carry.take(*_window_end(POSE, frozen, carry.confirm_frames, [3]), frame=frame)
    n_max = int(round(CARRY_MAX_S * RATE))
    held = [carry.apply(frozen, valid, frozen, none, frame + 1 + i)[1][3] for i in range(n_max + fade + 1)]
    assert all(held[:n_max + fade - 1]) and not held[-1]


def test_a_lost_joint_is_carried_from_the_window_and_a_root_never_is():
    carry = _carry()
    raw = POSE.copy()
    raw[2:] = np.nan  # the sensor lost the forearm and hand
    solved = POSE + [0.1, 0.0, 0.0]  # the window also moved the root
    solved_n, raws, valid, judged = _window_end(solved, raw, carry.confirm_frames, [0, 2, 3])
    valid[:, 2:] = False
    carry.take(solved_n, raws, valid, judged, frame=7)
    assert carry.held.tolist() == [False, False, True, True]


@pytest.fixture(scope="module")
def take_131(shared_data):
    return ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", RATE)


@pytest.mark.parametrize("kind", ["freeze", "swap", "dropout"])
def test_the_live_topic_mends_what_the_windows_found(take_131, kind):
    """CMU 131_01 at 30 Hz with the sensor protocol's errors of one kind: the live topic's error on
    the corrupted joint-frames falls below what the live path alone makes of them, and the
    untouched joint-frames move little."""
    truth = take_131.positions
    c = apply_sensor_errors(truth, _rng(0, kind, "131_01.bvh"), [kind], rate_hz=RATE, min_events=1)
    m = Motion(c.positions, c.confidence, np.arange(len(truth)) / RATE, RATE, KINECT_V2)
    errors = {}
    for carry in (False, True):
        cfg = dataclasses.replace(schedule_config("serve", RATE), live_carry=carry)
        live = clean_motion(m, cfg, topic="live")[0].positions
        e = np.linalg.norm(live - truth, axis=2)
        errors[carry] = (np.nanmean(e[c.corrupted]), np.nanmean(e[~c.corrupted]))
    (bad_off, good_off), (bad_on, good_on) = errors[False], errors[True]
    assert bad_on < 0.9 * bad_off, errors
    assert good_on < good_off + 0.002, errors  # collateral: within 2 mm


def test_the_live_topic_on_real_kinect_v1_legs_gets_closer_to_vicon(shared_data):
    """UI-PRMD (Kinect v1 + Vicon), every 60th repetition: the sensor loses and folds the legs in
    squats, lunges and sit-to-stand, and the carried window verdict brings the live topic's lower
    body (debiased error, pooled) well closer to the optical reference."""
    from streamfix.evaluation.paired import region_masks
    from streamfix.io.paired import find_takes, load_take

    refs = [r for r in find_takes(shared_data / "paired", subset="trustworthy") if r.dataset == "uiprmd"][::60]
    sums = {False: 0.0, True: 0.0}
    for ref in refs:
        take = load_take(ref)
        m = take.sensor
        lower = region_masks(m.skeleton.joint_names)["lower"] & take.referenced
        for carry in (False, True):
            cfg = dataclasses.replace(schedule_config("serve", m.rate_hz), live_carry=carry)
            y = clean_motion(m, cfg, topic="live")[0].positions
            deb = np.linalg.norm(remove_mean_offset(y, take.reference) - take.reference, axis=2)
            sums[carry] += float(np.nansum(deb[:, lower]))
    assert sums[True] < 0.85 * sums[False], sums


def test_the_compiled_carry_is_bit_identical_to_the_numpy_path(monkeypatch):
    """Kinect v2's tree, random verdicts taken every 10 frames, joints lost and found: the same
    outputs and the same state frame by frame with the kernel and with numpy."""
    from streamfix.core import kernels

    assert kernels.COMPILED
    J = KINECT_V2.n_joints
    levels = tree_levels(KINECT_V2.bone_array, J)
    rng = np.random.default_rng(3)
    pose = rng.normal(scale=0.3, size=(J, 3))
    runs = {}
    for compiled in (True, False):
        monkeypatch.setattr(kernels, "COMPILED", compiled)
        carry = WindowCarry(levels, J, RATE)
        rng = np.random.default_rng(4)
        outs = []
        for i in range(400):
            raw = pose + rng.normal(scale=0.05, size=(J, 3))
            valid = rng.random(J) > 0.1
            raw[~valid] = np.nan
            if i % 10 == 0:
                judged = rng.random((carry.confirm_frames, J)) < 0.4
                solved = pose + rng.normal(scale=0.2, size=(carry.confirm_frames, J, 3))
                carry.take(solved, np.repeat(raw[None], carry.confirm_frames, 0),
                           np.repeat(valid[None], carry.confirm_frames, 0), judged, i - 1)
            live = pose + rng.normal(scale=0.02, size=(J, 3))
            y, rec = carry.apply(raw, valid, live, rng.random(J) < 0.1, i)
            outs.append((y.copy(), rec.copy(), carry.held.copy(), carry.level.copy()))
        runs[compiled] = outs
    carried = 0
    for (y, rec, held, level), (y_ref, rec_ref, held_ref, level_ref) in zip(runs[True], runs[False]):
        assert np.array_equal(y, y_ref, equal_nan=True)
        assert np.array_equal(rec, rec_ref) and np.array_equal(held, held_ref) and np.array_equal(level, level_ref)
        carried += int((level_ref > 0).sum())
    assert carried > 300  # joints were carried, faded in and out


def test_the_threaded_engine_carries_the_verdict_too(take_131):
    """serve's mode: windows are solved in the shared pool and their results blended on a later
    poll, a frame or two after the synchronous engine would. The carry still mends the frozen
    limb on the live topic (each frame waits for the windows in flight, so the run is the same
    on any machine)."""
    from streamfix.frames import BodyFrame, SkeletonFrame
    from streamfix.streaming.engine import ThreadedStreamEngine

    truth = take_131.positions
    c = apply_sensor_errors(truth, _rng(0, "freeze", "131_01.bvh"), ["freeze"], rate_hz=RATE, min_events=1)
    errors = {}
    for carry in (False, True):
        cfg = dataclasses.replace(schedule_config("serve", RATE), live_carry=carry, threaded=True)
        engine = ThreadedStreamEngine(KINECT_V2, cfg, clean_on_poll=True)
        live = np.full_like(truth, np.nan)
        try:
            for i in range(len(truth)):
                frame = SkeletonFrame("s", i, int(i * 1e9 / RATE), KINECT_V2.name,
                                      [BodyFrame(0, c.positions[i], c.confidence[i])])
                out = engine.push(frame) + engine.poll()  # the poll hands the frame's windows to the pool
                deadline = time.monotonic() + 10.0
                while engine.metrics()["pending_windows"] and time.monotonic() < deadline:
                    time.sleep(0.001)
                out += engine.poll()
                for kind, f in out:
                    if kind == "live":
                        live[i] = f.bodies[0].positions
        finally:
            engine.close()
        e = np.linalg.norm(live - truth, axis=2)
        errors[carry] = float(np.nanmean(e[c.corrupted]))
    assert errors[True] < 0.85 * errors[False], errors
