"""The learned pose-dependent sensor bias (streamfix.core.pose_bias, streamfix.sensor_bias).

Pure math on real poses (UI-PRMD's Kinect v1 skeletons, ../shared/data/paired): a bias the
model can represent is recovered, the average offset is left alone, unfamiliar poses get
none, missing joints stay missing, runs of frames give what one pass gives. Then the real
thing: the shipped model is what `train-bias` makes from the shared data, its card says
so, and a model fitted without a person makes that person's output closer to Vicon.
"""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from streamfix.core.pose_bias import (body_frames, correction_gain, familiarity, fit_pose_bias, pose_bias,
                                      pose_features, remove_pose_bias)
from streamfix.core.reference_metrics import remove_mean_offset
from streamfix.io.pose_bias_model import load_pose_bias, save_pose_bias
from streamfix.sensor_bias import BIAS_LAYOUTS, MODELS_DIR, resolve_sensor_bias, shipped_model
from streamfix.skeletons import get_skeleton

LAYOUT = BIAS_LAYOUTS["kinect_v1_uiprmd"]
SKELETON = get_skeleton("kinect_v1_uiprmd")


@pytest.fixture(scope="module")
def sensor_poses(shared_data):
    """Every 20th trustworthy UI-PRMD repetition's raw Kinect v1 joints (real poses), metres, whole frames."""
    from streamfix.io.paired import find_takes, load_take

    refs = [r for r in find_takes(shared_data / "paired", subset="trustworthy") if r.dataset == "uiprmd"][::20]
    takes = [load_take(r).sensor.positions for r in refs]
    return [p[np.isfinite(p).all(axis=(1, 2))] for p in takes]  # the frames with every joint


def _fit(pairs, **kw):
    kw.setdefault("sensor_direction", LAYOUT.sensor_direction)
    return fit_pose_bias(pairs, skeleton=LAYOUT.skeleton, joint_names=SKELETON.joint_names,
                         frame_joints=LAYOUT.frame_joints, groups=LAYOUT.groups, corrected=LAYOUT.corrected,
                         follow=LAYOUT.follow, **kw)


def _planted_bias(pos: np.ndarray) -> np.ndarray:
    """A bias the model can represent: the right wrist off along the body's z by 6 cm times the
    forearm's body-frame y (a raised forearm reads forward), plus a constant 3 cm offset."""
    names = SKELETON.joint_names
    frames = body_frames(pos, tuple(names.index(n) for n in LAYOUT.frame_joints))
    fore = pos[:, names.index("RWrist")] - pos[:, names.index("RElbow")]
    fore_y = np.einsum("tj,tj->t", frames[:, 1], fore / np.linalg.norm(fore, axis=1, keepdims=True))
    bias = np.zeros_like(pos)
    bias[:, names.index("RWrist")] = (0.06 * fore_y + 0.03)[:, None] * frames[:, 2]
    return bias


def test_a_planted_pose_dependent_bias_is_recovered_and_the_average_offset_is_not(sensor_poses):
    train, test = sensor_poses[::2], sensor_poses[1::2]
    model = _fit([(p, p - _planted_bias(p)) for p in train], ridge=1e-5)
    wrist = SKELETON.joint_names.index("RWrist")
    frame_idx = tuple(SKELETON.joint_names.index(n) for n in LAYOUT.frame_joints)

    def in_body_frame(poses, bias_of):  # (frames, 3): the wrist's bias in each frame's body axes
        return np.concatenate([np.einsum("tij,tj->ti", body_frames(p, frame_idx), bias_of(p)[:, wrist]) for p in poses])

    truth = in_body_frame(test, _planted_bias)
    got = in_body_frame(test, lambda p: pose_bias(p, model))
    familiar = familiarity(np.concatenate([pose_features(p, model)[1] for p in test]), model) == 1.0  # not faded
    # the pose-dependent part is learned (on other takes than the fit's) ...
    varying = truth - truth.mean(axis=0)
    miss = np.abs((got - got.mean(axis=0)) - varying)[familiar]
    assert miss.max() < 0.1 * np.abs(varying).max()
    # ... the constant (3 cm plus the mean of the varying part) is not: over the training poses it averages out
    fitted = in_body_frame(train, lambda p: pose_bias(p, model))
    assert np.linalg.norm(fitted.mean(axis=0)) < 0.005 < np.linalg.norm(truth.mean(axis=0))
    # a joint with no bias planted gets (almost) none
    elbow = SKELETON.joint_names.index("LElbow")
    assert np.abs(np.concatenate([pose_bias(p, model)[:, elbow] for p in test])).max() < 2e-3


def _turned(pos: np.ndarray, degrees: float) -> np.ndarray:
    """``pos`` turned about the vertical axis through its waist (a person facing away from the camera)."""
    a = np.radians(degrees)
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    centre = pos[:, SKELETON.joint_names.index("Waist")].mean(axis=0)
    return (pos - centre) @ rot.T + centre


def test_a_bias_that_depends_on_where_the_sensor_sees_the_body_from_needs_the_sensor_direction(sensor_poses):
    """The same arm pose, the body turned: a depth sensor places the wrist by the side it sees.
    Turning the whole body leaves every limb's direction in the body frame as it was, so only
    the direction towards the sensor (the origin of camera space) can tell the two apart."""
    from streamfix.core.pose_bias import towards_sensor

    names = SKELETON.joint_names
    frame_idx = tuple(names.index(n) for n in LAYOUT.frame_joints)
    wrist = names.index("RWrist")

    def view_bias(pos):  # the wrist reads 8 cm deeper along the body's z the more the body is turned sideways
        frames = body_frames(pos, frame_idx)
        bias = np.zeros_like(pos)
        bias[:, wrist] = (0.08 * towards_sensor(pos, frames, frame_idx)[:, 0])[:, None] * frames[:, 2]
        return bias

    train = [_turned(p, a) for p in sensor_poses[::2] for a in (-40, -20, 0, 20, 40)]
    test = [_turned(p, a) for p in sensor_poses[1::2] for a in (-30, -10, 10, 30)]
    truth = np.concatenate([view_bias(p)[:, wrist] for p in test])
    varying = truth - truth.mean(axis=0)
    residual = {}
    for flag in (False, True):
        model = _fit([(p, p - view_bias(p)) for p in train], ridge=1e-5, sensor_direction=flag)
        assert model.sensor_direction is flag
        got = np.concatenate([pose_bias(p, model)[:, wrist] for p in test])
        familiar = familiarity(np.concatenate([pose_features(p, model)[1] for p in test]), model) == 1.0
        assert familiar.mean() > 0.5
        residual[flag] = np.abs((got - got.mean(axis=0)) - varying)[familiar].mean() / np.abs(varying).mean()
    assert residual[True] < 0.3 and residual[False] > 0.6, residual  # measured: 0.13 and 0.74


def test_poses_unlike_the_training_ones_are_not_corrected(sensor_poses):
    model = _fit([(p, p - _planted_bias(p)) for p in sensor_poses], ridge=1e-5)
    pose = sensor_poses[0][:5].copy()
    names = SKELETON.joint_names
    # the arms folded back through the trunk and the legs up to the chest: far from every training pose
    for side in "LR":
        sh, el, wr = (names.index(f"{side}{j}") for j in ("Shoulder", "Elbow", "Wrist"))
        hip, kn, an, ft = (names.index(f"{side}{j}") for j in ("Hip", "Knee", "Ankle", "Foot"))
        pose[:, el] = pose[:, sh] - (pose[:, el] - pose[:, sh])
        pose[:, wr] = pose[:, sh]
        pose[:, kn] = pose[:, hip] + np.array([0.0, 0.4, 0.0])
        pose[:, an] = pose[:, kn] + np.array([0.0, 0.4, 0.0])
        pose[:, ft] = pose[:, an] + np.array([0.0, 0.1, 0.0])
    assert (familiarity(pose_features(pose, model)[1], model) == 0.0).all()
    assert np.abs(pose_bias(pose, model)).max() == 0.0
    # and the real poses it was fitted on are, nearly all, corrected in full
    assert (familiarity(np.concatenate([pose_features(p, model)[1] for p in sensor_poses]), model) == 1.0).mean() > 0.9


def test_missing_joints_stay_missing_and_their_frames_are_not_corrected(sensor_poses):
    model = shipped_model("kinect_v1_uiprmd")
    pos = sensor_poses[1][:30].copy()
    pos[10, SKELETON.joint_names.index("LKnee")] = np.nan
    out, last = remove_pose_bias(pos, SKELETON.bone_array, model, correction_gain(30.0))
    assert np.isnan(out[10, SKELETON.joint_names.index("LKnee")]).all()
    assert np.isfinite(np.delete(out, 10, axis=0)).all() and np.isfinite(last).all()
    assert np.abs(pose_bias(pos, model)[10]).max() == 0.0  # the frame lacks a joint the features need


def test_runs_of_frames_give_what_one_pass_gives_and_bones_keep_their_lengths(sensor_poses):
    model = shipped_model("kinect_v1_uiprmd")
    pos, bones = sensor_poses[2], SKELETON.bone_array
    alpha = correction_gain(30.0)
    whole, _ = remove_pose_bias(pos, bones, model, alpha)
    pieces, last = [], None
    for a, b in ((0, 1), (1, 8), (8, 9), (9, len(pos))):
        out, last = remove_pose_bias(pos[a:b], bones, model, alpha, last)
        pieces.append(out)
    np.testing.assert_allclose(np.concatenate(pieces), whole, atol=1e-12)
    length = lambda p: np.linalg.norm(p[:, bones[:, 1]] - p[:, bones[:, 0]], axis=2)  # noqa: E731
    moved = np.linalg.norm(whole - pos, axis=2).mean()
    assert moved > 0.01  # it does correct (centimetres)
    # each frame stays (nearly) on its own bone lengths: far less change than the joints moved
    assert np.abs(length(whole) - length(pos)).mean() < 0.1 * moved


@pytest.mark.parametrize("compiled", [True, False])
def test_one_frame_at_a_time_gives_what_one_pass_gives(sensor_poses, monkeypatch, compiled):
    """The live topic's per-frame correction (compiled, or the numpy batch function on one
    frame without numba) is the batch correction frame by frame: a joint missing, a frame without a
    body frame, a frame whose trunk sits at the coordinate origin (not camera space: uncorrected) and a pose
    unlike the training ones (faded) included."""
    from streamfix.core import kernels
    from streamfix.core.pose_bias_live import LivePoseBias

    if compiled and not kernels.COMPILED:
        pytest.skip("numba not available")
    monkeypatch.setattr(kernels, "COMPILED", compiled)
    model = shipped_model("kinect_v1_uiprmd")
    pos, bones = sensor_poses[3][:60].copy(), SKELETON.bone_array
    pos[10, SKELETON.joint_names.index("LKnee")] = np.nan
    pelvis, neck = (SKELETON.joint_names.index(n) for n in LAYOUT.frame_joints[2:])
    pos[20] -= 0.5 * (pos[20, pelvis] + pos[20, neck])  # the trunk at the origin
    pos[30, SKELETON.joint_names.index("RWrist")] += np.array([0.0, 0.6, 0.0])  # an arm no one trained
    left, right = (SKELETON.joint_names.index(n) for n in LAYOUT.frame_joints[:2])
    pos[40, left] = pos[40, right]  # no body frame (a zero-length axis): uncorrected, no error raised
    alpha = correction_gain(30.0)
    whole, whole_last = remove_pose_bias(pos, bones, model, alpha)
    live = LivePoseBias(model, bones, alpha)
    frames, last = [], None
    for p in pos:
        out, last = live.step(p, last)
        frames.append(out)
    frames = np.array(frames)
    assert np.array_equal(np.isnan(frames), np.isnan(whole))
    np.testing.assert_allclose(frames, whole, atol=1e-12)
    np.testing.assert_allclose(last, whole_last, atol=1e-12)
    assert np.nanmax(np.abs(whole - pos)) > 0.02  # it does correct
    with pytest.raises(ValueError, match=r"\(22, 3\)"):
        live.step(pos[0, :20], None)


def test_model_files_round_trip_and_a_bad_one_is_named(tmp_path):
    model = shipped_model("kinect_v1_uiprmd")
    path = save_pose_bias(model, tmp_path / "m.npz")
    again = load_pose_bias(path)
    assert again.corrected == model.corrected and again.training_subjects == model.training_subjects
    assert again.sensor_direction is model.sensor_direction is True
    np.testing.assert_array_equal(again.weights, model.weights)
    # a version-1 file (before the direction towards the sensor existed) reads as one without it
    import json

    with np.load(path, allow_pickle=False) as z:
        arrays = {k: np.array(z[k]) for k in z.files}
    meta = json.loads(str(arrays.pop("meta")))
    meta["format"] = "streamfix-pose-bias-1"
    del meta["sensor_direction"]
    old = tmp_path / "v1.npz"
    np.savez(old, meta=np.array(json.dumps(meta)), **arrays)
    assert load_pose_bias(old).sensor_direction is False
    meta["format"] = "streamfix-pose-bias-9"
    np.savez(old, meta=np.array(json.dumps(meta)), **arrays)
    with pytest.raises(ValueError, match="pose-bias-9"):
        load_pose_bias(old)
    bad = tmp_path / "bad.npz"
    np.savez(bad, weights=np.zeros(3))
    with pytest.raises(ValueError, match="bad.npz"):
        load_pose_bias(bad)


def test_auto_picks_the_shipped_model_for_its_skeleton_only(tmp_path):
    assert resolve_sensor_bias("auto", SKELETON) is shipped_model("kinect_v1_uiprmd")
    assert resolve_sensor_bias("auto", get_skeleton("kinect_v2")) is None
    assert resolve_sensor_bias("off", SKELETON) is None and resolve_sensor_bias(None, SKELETON) is None
    path = save_pose_bias(shipped_model("kinect_v1_uiprmd"), tmp_path / "m.npz")
    with pytest.raises(ValueError, match="kinect_v2"):
        resolve_sensor_bias(str(path), get_skeleton("kinect_v2"))


def test_the_engine_emits_the_uncorrected_output_less_the_bias(shared_data):
    """What `serve` publishes (on clean and on live) and `clean` writes is the uncorrected
    engine output put through remove_pose_bias in one pass (the engine's runs of frames, and
    the live topic's single frames, change nothing)."""
    from streamfix.evaluation.registry import run_method
    from streamfix.io.paired import find_takes, load_take

    ref = [r for r in find_takes(shared_data / "paired", subset="trustworthy") if r.dataset == "uiprmd"][300]
    m = load_take(ref).sensor
    model = shipped_model(m.skeleton.name)
    for method in ("streamfix", "streamfix_serve", "streamfix_live"):
        run = lambda bias: run_method(method, m.positions, m.confidence, m.skeleton.bone_array, m.rate_hz,  # noqa: E731
                                      skeleton=m.skeleton, sensor_bias=bias)
        off, on = run("off"), run("auto")
        expected, _ = remove_pose_bias(off, m.skeleton.bone_array, model, correction_gain(m.rate_hz))
        np.testing.assert_allclose(on, expected, atol=1e-9)
        assert np.linalg.norm(on - off, axis=2).mean() > 0.005


@pytest.fixture(scope="module")
def engine_outputs(shared_data):
    from streamfix.sensor_bias.train import engine_outputs, paired_takes

    return engine_outputs(paired_takes(shared_data / "paired"))


def test_the_shipped_model_is_what_train_bias_makes_from_the_shared_data(engine_outputs):
    from streamfix.sensor_bias.card import card_path, file_sha256
    from streamfix.sensor_bias.train import fit_layout_model

    shipped = shipped_model("kinect_v1_uiprmd")
    again = fit_layout_model(engine_outputs)
    assert again.training_subjects == shipped.training_subjects == ("s01", "s02", "s03", "s04", "s05", "s06")
    np.testing.assert_allclose(again.weights, shipped.weights, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(again.centres, shipped.centres, rtol=1e-6, atol=1e-9)
    card = card_path(MODELS_DIR / "kinect_v1_uiprmd.npz").read_text()
    assert f"model-sha256: {file_sha256(MODELS_DIR / 'kinect_v1_uiprmd.npz')}" in card
    assert f"training-takes: {len(engine_outputs)}" in card
    assert f"training-frames: {sum(len(t.output) for t in engine_outputs)}" in card
    assert "commercial use allowed" in card and "PDDL" in card


def test_a_model_fitted_without_a_person_brings_their_output_closer_to_vicon(engine_outputs):
    """Held-out people, the phenomenon rather than these files: for two people, a model
    fitted on the other four lowers the debiased error of both body halves by 3 % or more
    and the raw error too (the shared data's six-fold figures: the model card)."""
    from streamfix.evaluation.paired import body_region
    from streamfix.sensor_bias.train import fit_layout_model

    lower = np.array([body_region(n) == "lower" for n in SKELETON.joint_names])
    for held in ("s03", "s05"):
        model = fit_layout_model([t for t in engine_outputs if t.subject not in ("s03", "s05")])
        sums = np.zeros((2, 2, 2))  # region, debiased/raw, before/after
        for t in (t for t in engine_outputs if t.subject == held):
            ref, before = t.reference.astype(float), t.output.astype(float)
            after, _ = remove_pose_bias(before, t.bones, model, correction_gain(t.rate_hz))
            for k, y in enumerate((before, after)):
                for r, joints in enumerate((~lower, lower)):
                    deb = np.linalg.norm(remove_mean_offset(y, ref) - ref, axis=2)[:, joints]
                    raw = np.linalg.norm(y - ref, axis=2)[:, joints]
                    sums[r, 0, k] += np.nanmean(deb)
                    sums[r, 1, k] += np.nanmean(raw)
        ratio = sums[..., 1] / sums[..., 0]
        assert (ratio[:, 0] < 0.97).all() and (ratio[:, 1] < 0.99).all(), (held, ratio)


def test_coordinates_that_are_not_the_sensor_s_camera_space_get_little_or_no_correction(engine_outputs):
    """The direction towards the sensor assumes camera space (the sensor at the origin). With the
    origin moved behind a held-out person the body is seen from a side the training never had,
    and the correction fades (at the familiarity's weight 1 it raised the upper body's error by
    a quarter); with the origin on the body (a take re-centred on the person) nothing is corrected."""
    from streamfix.core.pose_bias import MIN_SENSOR_DISTANCE_M
    from streamfix.evaluation.paired import body_region
    from streamfix.sensor_bias.train import fit_layout_model

    upper = np.array([body_region(n) == "upper" for n in SKELETON.joint_names])
    model = fit_layout_model([t for t in engine_outputs if t.subject != "s03"])
    behind = np.array([0.0, 0.0, 5.0])  # UI-PRMD's camera looks along -z: the origin ends up behind the body
    sums = np.zeros(3)
    for t in [t for t in engine_outputs if t.subject == "s03"][::4]:
        ref, before = t.reference.astype(float), t.output.astype(float)
        moved, _ = remove_pose_bias(before + behind, t.bones, model, correction_gain(t.rate_hz))
        here, _ = remove_pose_bias(before, t.bones, model, correction_gain(t.rate_hz))
        for k, y in enumerate((before, moved - behind, here)):
            sums[k] += np.nanmean(np.linalg.norm(remove_mean_offset(y, ref) - ref, axis=2)[:, upper])
    assert sums[2] < 0.95 * sums[0]  # in camera space it corrects
    assert sums[1] < 1.05 * sums[0], sums  # seen from behind: about as the sensor had it
    pos = engine_outputs[0].output.astype(float)
    centred = pos - pos[0, SKELETON.joint_names.index("Waist")]
    trunk = 0.5 * np.linalg.norm(centred[:, SKELETON.joint_names.index("Waist")]
                                 + centred[:, SKELETON.joint_names.index("Neck")], axis=1)
    near = trunk < MIN_SENSOR_DISTANCE_M
    assert near.any()
    assert not pose_bias(centred, model)[near].any()


def test_the_lower_body_is_predicted_from_the_legs_and_trunk_only(sensor_poses):
    """``predictors``: a leg joint's correction reads the legs' and the trunk's features, never
    the arms' (their weights are exactly 0), and a bias that depends on the leg's own fold is
    still recovered."""
    from streamfix.core.pose_bias import feature_groups

    names = SKELETON.joint_names
    knee, ankle = (names.index(n) for n in ("LKnee", "LAnkle"))
    frame_idx = tuple(names.index(n) for n in LAYOUT.frame_joints)

    def knee_bias(pos):  # the knee reads 5 cm forward times how far the shin points forward
        frames = body_frames(pos, frame_idx)
        shin = pos[:, ankle] - pos[:, knee]
        shin_z = np.einsum("tj,tj->t", frames[:, 2], shin / np.linalg.norm(shin, axis=1, keepdims=True))
        bias = np.zeros_like(pos)
        bias[:, knee] = (0.05 * shin_z)[:, None] * frames[:, 2]
        return bias

    train, test = sensor_poses[::2], sensor_poses[1::2]
    model = _fit([(p, p - knee_bias(p) - _planted_bias(p)) for p in train], ridge=1e-5,
                 predictors=LAYOUT.predictor_groups())
    arms = feature_groups(names, LAYOUT.groups, model.sensor_direction) == 0
    k = LAYOUT.corrected.index("LKnee")
    assert not model.weights[arms, 3 * k:3 * k + 3].any()
    assert model.weights[~arms, 3 * k:3 * k + 3].any()
    w = LAYOUT.corrected.index("RWrist")  # the upper body keeps every group
    assert model.weights[arms, 3 * w:3 * w + 3].any() and model.weights[~arms, 3 * w:3 * w + 3].any()
    truth = np.concatenate([knee_bias(p)[:, knee] for p in test])
    got = np.concatenate([pose_bias(p, model)[:, knee] for p in test])
    familiar = familiarity(np.concatenate([pose_features(p, model)[1] for p in test]), model) == 1.0
    varying = truth - truth.mean(axis=0)
    assert np.abs((got - got.mean(axis=0)) - varying)[familiar].max() < 0.15 * np.abs(varying).max()


def test_standing_legs_stay_where_the_sensor_has_them_while_the_arms_exercise(engine_outputs):
    """UI-PRMD's shoulder exercises (m07-m10): the sensor tracks the standing legs well. A model
    fitted without the person must not move them with the arms: with the legs' correction read
    from the legs and trunk alone, their debiased error grows far less than with every feature."""
    from streamfix.evaluation.paired import body_region
    from streamfix.sensor_bias.train import fit_layout_model

    lower = np.array([body_region(n) == "lower" for n in SKELETON.joint_names])
    held = ("s03", "s05")
    train = [t for t in engine_outputs if t.subject not in held]
    models = {"legs": fit_layout_model(train),
              "all": fit_layout_model(train, dataclasses.replace(LAYOUT, predictors={}))}
    err = {name: [] for name in ("before", *models)}
    for t in engine_outputs:
        if t.subject not in held or t.key.split("_")[1] not in ("m07", "m08", "m09", "m10"):
            continue
        ref, before = t.reference.astype(float), t.output.astype(float)
        outs = {"before": before}
        outs.update({n: remove_pose_bias(before, t.bones, m, correction_gain(t.rate_hz))[0] for n, m in models.items()})
        for name, y in outs.items():
            err[name].append(np.linalg.norm(remove_mean_offset(y, ref) - ref, axis=2)[:, lower].ravel())
    mean = {n: float(np.nanmean(np.concatenate(v))) for n, v in err.items()}
    assert mean["legs"] - mean["before"] < 0.6 * (mean["all"] - mean["before"]), mean


def test_train_bias_and_clean_refuse_what_they_cannot_use(tmp_path):
    bad = subprocess.run([sys.executable, "-m", "streamfix", "train-bias", "--out", str(tmp_path / "m.txt")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and ".npz" in bad.stderr
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a model")
    out = subprocess.run([sys.executable, "-m", "streamfix", "clean", "in.csv", str(tmp_path / "o.csv"),
                          "--sensor-bias", str(junk)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--sensor-bias" in out.stderr and "junk.npz" in out.stderr


def test_the_python_api_takes_the_same_setting(shared_data):
    import streamfix
    from streamfix.evaluation.registry import run_method
    from streamfix.io.paired import find_takes, load_take

    ref = [r for r in find_takes(shared_data / "paired", subset="trustworthy") if r.dataset == "uiprmd"][40]
    m = load_take(ref).sensor
    x = np.where(m.confidence[..., None] > 0, m.positions, np.nan)
    off, _ = streamfix.clean(x, m.rate_hz, "kinect_v1_uiprmd", m.confidence, sensor_bias="off")
    on, _ = streamfix.clean(x, m.rate_hz, "kinect_v1_uiprmd", m.confidence)
    want = run_method("streamfix", m.positions, m.confidence, m.skeleton.bone_array, m.rate_hz, skeleton=m.skeleton,
                      sensor_bias="off")
    np.testing.assert_allclose(off, want, atol=1e-12)
    assert np.linalg.norm(on - off, axis=2).mean() > 0.005
