"""The sensor error model: each kind corrupts exactly what its mask says, reproducibly, as documented."""
from __future__ import annotations

import re
from dataclasses import fields

import numpy as np
import pytest

from streamfix.evaluation.sensor import ground_truth
from streamfix.motion import CONFIDENCE_INFERRED
from streamfix.sim.sensor_errors import (
    ASSUMED_PARAMETERS,
    DISTAL_SEGMENTS,
    KINDS,
    MIRROR,
    MIX_KINDS,
    PARENT,
    SWAP_LIMBS,
    SensorErrorParams,
    apply_sensor_errors,
)
from streamfix.skeletons import KINECT_V2


@pytest.fixture(scope="module")
def truth(shared_data) -> np.ndarray:
    """CMU 131_01 (walking) as Kinect v2 joints in the camera frame at 30 Hz: 249 frames."""
    return ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", 30.0).positions


@pytest.mark.parametrize("kind", KINDS)
def test_each_kind_changes_exactly_its_mask(truth, kind):
    for seed in range(4):
        c = apply_sensor_errors(truth, np.random.default_rng(seed), [kind], min_events=1)
        mask = c.masks[kind]
        assert set(c.masks) == {kind} and mask.shape == truth.shape[:2] and mask.any()
        # outside the mask: bit for bit the ground truth, tracked
        assert np.array_equal(c.positions[~mask], truth[~mask])
        assert (c.confidence[~mask] == 1.0).all()
        # inside: every joint-frame changed (its position, or for ``flagged`` only its flag)
        moved = np.linalg.norm(np.nan_to_num(c.positions, nan=1e6) - truth, axis=2)
        if kind == "flagged":
            assert np.array_equal(c.positions, truth) and (c.confidence[mask] == CONFIDENCE_INFERRED).all()
            frozen = apply_sensor_errors(truth, np.random.default_rng(seed), ["freeze"], min_events=1)
            assert np.array_equal(frozen.masks["freeze"], mask)  # the freeze kind's stretches, left right
            continue
        assert (moved[mask] > 1e-9).all()
        if kind == "noise":
            assert mask.all()
        elif kind == "dropout":
            assert np.isnan(c.positions[mask]).all() and (c.confidence[mask] == 0).all()
        elif kind == "freeze":
            assert (c.confidence[mask] == CONFIDENCE_INFERRED).all()
        else:
            assert np.isfinite(c.positions).all() and (c.confidence == 1.0).all()
            assert mask.mean() < 0.2  # an event, not the whole take


def test_reproducible_by_seed(truth):
    a = apply_sensor_errors(truth, np.random.default_rng(7))
    b = apply_sensor_errors(truth, np.random.default_rng(7))
    c = apply_sensor_errors(truth, np.random.default_rng(8))
    assert np.array_equal(a.positions, b.positions, equal_nan=True)
    assert np.array_equal(a.confidence, b.confidence)
    assert all(np.array_equal(a.masks[k], b.masks[k]) for k in a.masks)
    assert not np.array_equal(a.positions, c.positions, equal_nan=True)
    assert list(a.masks) == list(MIX_KINDS)


def test_swap_exchanges_mirror_joints(truth):
    assert (MIRROR[MIRROR] == np.arange(KINECT_V2.n_joints)).all()
    names = KINECT_V2.joint_names
    assert names[MIRROR[KINECT_V2.index("HandTipLeft")]] == "HandTipRight"
    assert names[MIRROR[KINECT_V2.index("SpineMid")]] == "SpineMid"
    seen = set()
    for seed in range(12):
        c = apply_sensor_errors(truth, np.random.default_rng(seed), ["swap"], min_events=1)
        mask = c.masks["swap"]
        frames = np.flatnonzero(mask.any(axis=1))
        for limb, left in SWAP_LIMBS.items():
            both = np.concatenate([left, MIRROR[left]])
            hit = mask[:, both].all(axis=1)
            if hit.any():
                seen.add(limb)
                t = np.flatnonzero(hit)
                assert np.array_equal(c.positions[np.ix_(t, left)], truth[np.ix_(t, MIRROR[left])])
                assert np.array_equal(c.positions[np.ix_(t, MIRROR[left])], truth[np.ix_(t, left)])
        # runs last swap_frames (5..17 frames by default), never a single frame
        runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], mask.any(axis=1), [0]]).astype(int))))[::2]
        assert frames.size and runs.min() >= SensorErrorParams().swap_frames[0] - 0.5
    assert "leg" in seen  # legs swap 25x more often than arms (estimated)


@pytest.mark.parametrize("still", [1.0, 0.0])
def test_frozen_limbs_hold_their_pose_and_drifting_ones_move_slowly(truth, still):
    # one stretch per take (rate 0, at least one event), frozen or drifting
    p = SensorErrorParams(freeze_still_fraction=still, freeze_rate_hz=0.0)
    for seed in range(6):
        c = apply_sensor_errors(truth, np.random.default_rng(seed), ["freeze"], params=p, min_events=1)
        mask = c.masks["freeze"]
        seg = next(s for s in DISTAL_SEGMENTS if mask[:, s].all(axis=1).any() and mask[:, s].sum() == mask.sum())
        frames = np.flatnonzero(mask[:, seg[0]])
        assert np.array_equal(frames, np.arange(frames[0], frames[-1] + 1))
        assert 0.5 * 30 - 1 <= frames.size <= 3.0 * 30 + 1  # 0.5-3 s
        anchor = PARENT[seg[0]]
        assert not mask[:, anchor].any()  # it hangs from a tracked joint
        pose = c.positions[frames][:, seg] - c.positions[frames, anchor][:, None]
        speed = np.linalg.norm(np.diff(pose, axis=0), axis=2) * 30.0  # m/s of the pose
        true_pose = truth[frames][:, seg] - truth[frames, anchor][:, None]
        true_speed = np.linalg.norm(np.diff(true_pose, axis=0), axis=2) * 30.0
        before = truth[frames[0] - 1, seg] - truth[frames[0] - 1, anchor]
        if still:
            assert np.allclose(speed, 0.0, atol=1e-9)  # constant relative to the body
            assert np.allclose(pose[0], before)  # the pose of the frame before the failure
        else:
            assert np.allclose(speed, p.drift_speed_m_s, rtol=1e-6)
            assert p.drift_speed_m_s < 0.5 * true_speed.mean()  # slow next to the real limb
            assert np.allclose(np.linalg.norm(pose[0] - before, axis=1), p.drift_speed_m_s / 30.0)


def test_depth_noise_larger_than_lateral():
    p = SensorErrorParams()
    assert p.noise_sigma_m[2] > p.noise_sigma_m[0] and p.noise_sigma_m[2] > p.noise_sigma_m[1]
    still = np.tile(np.linspace(0, 1, KINECT_V2.n_joints * 3).reshape(1, -1, 3), (4000, 1, 1))
    c = apply_sensor_errors(still, np.random.default_rng(0), ["noise"])
    n = c.positions - still
    sd = n.reshape(-1, 3).std(axis=0)
    assert np.allclose(sd, p.noise_sigma_m, rtol=0.1)
    assert sd[2] > sd[0] and sd[2] > sd[1]
    lag1 = np.mean(n[1:] * n[:-1]) / np.mean(n * n)
    assert lag1 == pytest.approx(p.noise_rho, abs=0.03)  # temporally correlated, as estimated


def test_bad_input_names_what_is_wrong(truth):
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match=r"\(T, 25, 3\).*got \(10, 24, 3\)"):
        apply_sensor_errors(np.zeros((10, 24, 3)), rng)
    with pytest.raises(ValueError, match="unknown error kind.*blur.*expected"):
        apply_sensor_errors(truth, rng, ["noise", "blur"])
    gappy = truth.copy()
    gappy[3, 4] = np.nan
    with pytest.raises(ValueError, match="1 joint-frames are missing"):
        apply_sensor_errors(gappy, rng)
    with pytest.raises(ValueError, match="noise_rho must be in"):
        SensorErrorParams(noise_rho=1.0)
    with pytest.raises(ValueError, match="swap_frames must be"):
        SensorErrorParams(swap_frames=(9.0, 4.0))


def _doc_table(project_root) -> dict[str, str]:
    text = (project_root / "docs" / "SENSOR_ERRORS.md").read_text()
    block = text.split("<!-- BEGIN PARAMETERS", 1)[1].split("<!-- END PARAMETERS -->", 1)[0]
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \|", block, flags=re.M)
    return {name: value.strip() for name, value in rows}


def test_defaults_equal_the_documented_estimates(project_root):
    table = _doc_table(project_root)
    p = SensorErrorParams()
    assert set(table) == {f.name for f in fields(p)} - set(ASSUMED_PARAMETERS)
    text = (project_root / "docs" / "SENSOR_ERRORS.md").read_text()
    for name in ASSUMED_PARAMETERS:  # written down beside the table, with their values
        value = getattr(p, name)
        shown = f"{value:g}" if np.isscalar(value) else "-".join(f"{v:g}" for v in value)
        assert f"`{name}` {shown}" in text, name
    for name, text in table.items():
        documented = [float(v) for v in text.split(",")]
        value = np.atleast_1d(np.asarray(getattr(p, name), dtype=float))
        assert value.tolist() == pytest.approx(documented, rel=1e-6), name
