"""Foot support (core/support.py), joint roles from names (limbs.py), and the seam-free
overlap-add (engine.handover_weights), on constructed motion and on real recordings."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.support import SupportConfig, plant_supporting_feet, smooth_planted, two_bone_ik, up_direction
from streamfix.limbs import limb_layout, mirror_index
from streamfix.skeletons import get_skeleton

KV2 = get_skeleton("kinect_v2")
RATE = 30.0


def _standing(T: int) -> np.ndarray:
    """A still Kinect v2 stick figure, y up, feet on the floor at y = 0.05 m."""
    L = limb_layout(KV2)
    x = np.zeros((T, 25, 3))
    names = KV2.joint_names
    pos = {"SpineBase": (0, 1.0, 0), "SpineMid": (0, 1.25, 0), "SpineShoulder": (0, 1.45, 0), "Neck": (0, 1.5, 0),
           "Head": (0, 1.65, 0)}
    for side, sx in (("Left", -0.1), ("Right", 0.1)):
        pos.update({f"Hip{side}": (sx, 0.95, 0), f"Knee{side}": (sx, 0.52, 0), f"Ankle{side}": (sx, 0.1, 0),
                    f"Foot{side}": (sx, 0.05, -0.12), f"Shoulder{side}": (2 * sx, 1.42, 0),
                    f"Elbow{side}": (2.6 * sx, 1.15, 0), f"Wrist{side}": (2.8 * sx, 0.9, 0),
                    f"Hand{side}": (2.8 * sx, 0.83, 0), f"HandTip{side}": (2.8 * sx, 0.75, 0),
                    f"Thumb{side}": (2.6 * sx, 0.85, -0.03)})
    for j, n in enumerate(names):
        x[:, j] = pos[n]
    assert L.legs is not None
    return x


def _fold_legs(x: np.ndarray, lo: int, hi: int, drop: float) -> np.ndarray:
    """The sensor failure: pelvis and hips go down by ``drop`` m and the feet come up with them."""
    y = x.copy()
    ramp = np.zeros(len(x))
    ramp[lo:hi] = np.sin(np.linspace(0, np.pi, hi - lo))
    y[:, :, 1] -= (drop * ramp)[:, None]  # the whole body moves down, legs rigid: feet go below...
    legs = limb_layout(KV2).legs
    for s in range(2):  # ...then the sensor folds the legs up: feet rise above the floor
        for c, lift in ((2, 2.0), (3, 2.0), (1, 1.0)):  # feet 40 cm up at the deepest, as on UI-PRMD
            y[:, legs[s, c], 1] += (drop * lift * ramp)
    return y


@pytest.mark.parametrize("name", ["kinect_v2", "azure_kinect", "mediapipe_pose"])
def test_layouts_find_legs_and_mirrors(name):
    skel = get_skeleton(name)
    L = limb_layout(skel)
    assert L.legs is not None and L.legs.shape == (2, 4) and L.shoulders is not None
    names = skel.joint_names
    for s, word in enumerate(("left", "right")):
        assert all(word in names[j].lower() for j in L.legs[s])
    mirror = mirror_index(skel)
    assert (mirror[mirror] == np.arange(len(names))).all()  # an involution
    assert mirror[L.legs[0, 1]] == L.legs[1, 1] and mirror[L.shoulders[0]] == L.shoulders[1]


def test_bvh_layout_names(shared_data):
    from streamfix.io.bvh import read_bvh

    skel = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh").skeleton
    L = limb_layout(skel)
    assert [skel.joint_names[j] for j in L.legs[0]] == ["LeftHip", "LeftKnee", "LeftAnkle", "LeftToe"]


def test_two_bone_ik_keeps_lengths_and_bends_towards_hint():
    rng = np.random.default_rng(0)
    root = rng.normal(size=(50, 3))
    end = root + rng.normal(size=(50, 3)) * 0.3
    bend = rng.normal(size=(50, 3))
    mid = two_bone_ik(root, end, 0.45, 0.42, bend)
    reach = np.linalg.norm(end - root, axis=1) < 0.87
    assert np.allclose(np.linalg.norm(mid - root, axis=1), 0.45, atol=1e-9)
    assert np.allclose(np.linalg.norm(end - mid, axis=1)[reach], 0.42, atol=1e-6)
    d = (end - root) / np.linalg.norm(end - root, axis=1, keepdims=True)
    off = mid - root - np.sum((mid - root) * d, axis=1, keepdims=True) * d
    assert (np.sum(off * bend, axis=1)[reach] >= -1e-9).all()


def _lean_towards_camera(x: np.ndarray, degrees: np.ndarray) -> np.ndarray:
    """``x`` with each frame's upper body (everything above the hips) turned about the hip
    line by ``degrees`` (T,) towards -z, the camera's side: a squatter's forward lean."""
    names = KV2.joint_names
    upper = [j for j, n in enumerate(names) if not any(w in n for w in ("Hip", "Knee", "Ankle", "Foot", "SpineBase"))]
    pivot = x[:, names.index("SpineBase")]
    a = np.radians(degrees)[:, None]
    y = x.copy()
    rel = x[:, upper] - pivot[:, None]
    y[:, upper, 1] = pivot[:, None, 1] + np.cos(a) * rel[..., 1] + np.sin(a) * rel[..., 2]
    y[:, upper, 2] = pivot[:, None, 2] - np.sin(a) * rel[..., 1] + np.cos(a) * rel[..., 2]
    return y


def test_up_is_the_axis_the_trunk_stood_along_however_far_it_leans_later():
    """A deep squat leans the trunk 40-62 deg towards the camera for seconds (UI-PRMD): the
    median trunk direction of such a context is no axis at all (or the camera's z axis), but
    the frames where the person stood upright say which axis is up."""
    legs, shoulders = limb_layout(KV2).legs, limb_layout(KV2).shoulders
    T = 90
    for lean in (40.0, 62.0):
        deg = np.r_[np.zeros(10), np.full(T - 10, lean)]  # upright for a third of a second, then leaning
        up = up_direction(_lean_towards_camera(_standing(T), deg), legs, shoulders)
        assert np.allclose(up, [0, 1, 0]), (lean, up)
        # no upright frame in the context: the old rule, the median trunk (snapped within 32 deg)
        up = up_direction(_lean_towards_camera(_standing(T), np.full(T, lean)), legs, shoulders)
        assert not np.allclose(up, [0, 1, 0]), (lean, up)
    # a camera tilted 25 deg: no frame stands along an axis; the median trunk snaps to y as before
    up = up_direction(_lean_towards_camera(_standing(T), np.full(T, 25.0)), legs, shoulders)
    assert np.allclose(up, [0, 1, 0])
    # a camera tilted 40 deg: no axis is near, the trunk's own direction is up
    up = up_direction(_lean_towards_camera(_standing(T), np.full(T, 40.0)), legs, shoulders)
    assert 30.0 < np.degrees(np.arccos(up[1])) < 41.0 and up[2] < 0  # the hip-to-shoulder line leans a little less


def test_folded_legs_are_planted_and_standing_is_untouched():
    truth = _standing(90)
    legs = limb_layout(KV2).legs
    up = up_direction(truth, legs, limb_layout(KV2).shoulders)
    assert np.allclose(up, [0, 1, 0])
    same, w, _ = plant_supporting_feet(truth, legs, up, RATE)
    assert not w.any() and np.array_equal(same, truth)
    bad = _fold_legs(truth, 20, 80, 0.4)
    fixed, w, floor = plant_supporting_feet(bad, legs, up, RATE)
    assert abs(floor - 0.05) < 0.01
    feet = legs[:, 2:].ravel()
    err_in = np.linalg.norm(bad[:, feet] - truth[:, feet], axis=2).mean()
    err_out = np.linalg.norm(fixed[:, feet] - truth[:, feet], axis=2).mean()
    assert err_out < 0.35 * err_in  # lifts below tol_lo_m are left alone by design
    full = w == 1.0
    assert full.sum() > 20
    # anchored where the foot last stood (within SupportConfig.tol_lo_m / 2 of the floor)
    assert np.linalg.norm(fixed[full][:, feet] - truth[full][:, feet], axis=2).max() < SupportConfig().tol_lo_m / 2
    others = np.setdiff1d(np.arange(25), legs[:, 1:].ravel())
    assert np.array_equal(fixed[:, others], bad[:, others])  # only knees, ankles, feet move


def test_one_foot_lifted_or_a_short_flight_is_left_alone():
    truth = _standing(90)
    legs = limb_layout(KV2).legs
    up = np.array([0.0, 1.0, 0.0])
    step = truth.copy()
    step[20:70, legs[0, 2:], 1] += 0.3  # one leg raised: the other foot still supports
    assert not plant_supporting_feet(step, legs, up, RATE)[1].any()
    jump = truth.copy()
    jump[40:46, :, 1] += 0.25  # a 0.2 s jump flight: shorter than min_run_s
    assert not plant_supporting_feet(jump, legs, up, RATE, cfg=SupportConfig(min_run_s=0.3))[1].any()


def test_smooth_planted_smooths_planted_joints_only_and_fades_in():
    rng = np.random.default_rng(3)
    T, J = 120, 4
    t = np.arange(T) / RATE
    truth = np.zeros((T, J, 3))
    truth[..., 0] = 0.2 * np.sin(2 * np.pi * 0.3 * t)[:, None]  # slow motion the smoother must keep
    noisy = truth + rng.normal(scale=0.01, size=truth.shape)
    noisy[50, 2] = np.nan  # a missing sample stays missing
    weight = np.zeros((T, J))
    weight[30:90, 1:3] = 1.0  # joints 1 and 2 planted for 2 s
    out = smooth_planted(noisy, weight, RATE, 1.0)
    assert np.array_equal(out[:, [0, 3]], noisy[:, [0, 3]])  # never planted: untouched
    assert np.isnan(out[50, 2]).all() and np.isfinite(np.delete(out[:, 2], 50, axis=0)).all()
    mid = slice(40, 80)
    jit = lambda y: np.nanmean(np.linalg.norm(y[2:] - 2 * y[1:-1] + y[:-2], axis=-1))  # noqa: E731
    assert jit(out[mid, 1]) < 0.25 * jit(noisy[mid, 1])
    err = lambda y: np.nanmean(np.linalg.norm(y - truth[mid, 1], axis=-1))  # noqa: E731
    assert err(out[mid, 1]) < 0.5 * err(noisy[mid, 1])
    # far from the planted stretch nothing changes; next to it the smoother fades in
    assert np.array_equal(out[:10, 1], noisy[:10, 1])
    moved = np.linalg.norm(out[:, 1] - noisy[:, 1], axis=1)
    assert moved[15:30].max() > 0 and np.array_equal(smooth_planted(noisy, np.zeros((T, J)), RATE, 1.0), noisy, equal_nan=True)


def _engine_clean(motion):
    from streamfix.streaming.engine import EngineConfig
    from streamfix.streaming.offline import clean_motion

    return clean_motion(motion, EngineConfig(rate_hz=motion.rate_hz))[0]


def test_engine_plants_folded_legs_and_flags_them():
    from streamfix.motion import Motion

    truth = _standing(150)
    bad = _fold_legs(truth, 40, 120, 0.4)
    bad = bad + np.random.default_rng(1).normal(scale=0.004, size=bad.shape)
    m = Motion(bad, np.ones((150, 25)), np.arange(150) / RATE, RATE, KV2)
    out = _engine_clean(m)
    ankles = limb_layout(KV2).legs[:, 2]
    e_in = np.linalg.norm(bad[40:120, ankles] - truth[40:120, ankles], axis=2).mean()
    e_out = np.linalg.norm(out.positions[40:120, ankles] - truth[40:120, ankles], axis=2).mean()
    assert e_out < 0.3 * e_in
    assert out.recovered[60:100, ankles].all()  # replaced values are flagged recovered


def test_no_seam_at_window_handovers(shared_data):
    """Mean second difference of serve's clean output on the two frames around each window
    hand-over (where the blend passes a frame to the newer window,
    ``streamfix.streaming.blending.handover_frames``) is within 1.1x of that on the other
    frames (issue 8), on the longest real Kinect take (measured 1.075; its input 0.72)."""
    from streamfix.core.metrics import seam_jitter
    from streamfix.io.kinect_csv import read_kinect_csv
    from streamfix.streaming.engine import EngineConfig
    from streamfix.streaming.offline import clean_motion

    motion = read_kinect_csv(shared_data / "kinect_v2" / "seated_joints.csv")
    cfg = EngineConfig(rate_hz=motion.rate_hz)
    out, met = clean_motion(motion, cfg)
    assert met["windows_solved"] > 30
    seam = cfg.handover_frames(motion.n_frames)
    on, off = seam_jitter(out.positions, seam, cfg.hop)
    assert on / off < 1.1


def test_plant_window_on_a_layout_without_shoulders():
    """Legs but no shoulders (a lower-body marker set): the window stage must still run
    (its joint list was once built with float indices there)."""
    from streamfix.skeletons import Skeleton
    from streamfix.streaming.support import plant_window

    legs = limb_layout(KV2).legs
    keep = np.concatenate([[0], legs.ravel()])  # SpineBase and both legs
    names = tuple(KV2.joint_names[j] for j in keep)
    index = {j: i for i, j in enumerate(keep)}
    bones = tuple((index[a], index[b]) for a, b in KV2.bones if a in index and b in index)
    skel = Skeleton("legs_only", names, bones)
    assert limb_layout(skel).shoulders is None and limb_layout(skel).legs is not None
    truth = _standing(90)[:, keep]
    fixed, weight = plant_window(truth, np.ones(truth.shape[:2], dtype=bool), skel, np.array(bones), None, RATE)
    assert fixed.shape == truth.shape and not weight.any()
