"""The least movement rigid bones cost (streamfix.core.rigid_bound): exact on small cases,
never above what a real rigidifying projection moves."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.bone_projection import project_bone_lengths_pbd
from streamfix.core.rigid_bound import least_shift_to_rigid
from streamfix.io import read_motion


def test_small_chains_have_their_exact_least_movement():
    bones = np.array([[0, 1], [1, 2]])
    x = np.array([[[0.0, 0, 0], [0.30, 0, 0], [0.62, 0, 0]]])  # second bone 2 cm long of 0.30
    everyone = np.ones((1, 3), dtype=bool)
    lengths = np.array([0.30, 0.30])
    assert least_shift_to_rigid(x, everyone, everyone, bones, lengths)[0] == pytest.approx(0.02)
    free_tip = np.array([[True, True, False]])  # the tip may move for nothing
    assert least_shift_to_rigid(x, everyone, free_tip, bones, lengths)[0] == pytest.approx(0.0, abs=1e-12)
    both = np.array([[[0.0, 0, 0], [0.31, 0, 0], [0.62, 0, 0]]])  # both 1 cm long: move the shared joint once
    assert least_shift_to_rigid(both, everyone, everyone, bones, lengths)[0] == pytest.approx(0.01)
    assert least_shift_to_rigid(both, everyone, everyone, bones, lengths, keep=0.5)[0] == pytest.approx(0.005)
    unseen = np.array([[True, True, False]])  # a bone without both ends observed is not constrained
    assert least_shift_to_rigid(x, unseen, everyone, bones, lengths)[0] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="keep"):
        least_shift_to_rigid(x, everyone, everyone, bones, lengths, keep=1.0)


def test_a_projection_to_rigid_bones_moves_the_joints_at_least_the_bound(shared_data):
    m = read_motion(shared_data / "kinect_v2" / "Ges04_comehere.csv")
    x, bones = m.positions, m.skeleton.bone_array
    observed = np.isfinite(x).all(axis=2) & (m.confidence > 0)
    tracked = observed & (m.confidence >= 1.0)
    lengths = np.nanmedian(np.linalg.norm(x[:, bones[:, 1]] - x[:, bones[:, 0]], axis=2), axis=0)
    bound = least_shift_to_rigid(x, observed, tracked, bones, lengths)
    y = project_bone_lengths_pbd(np.nan_to_num(x), bones, lengths, 200, np.ones(x.shape[:2]))
    moved = np.where(tracked, np.linalg.norm(y - x, axis=2), 0.0).sum(axis=1)
    left = np.abs(np.linalg.norm(y[:, bones[:, 1]] - y[:, bones[:, 0]], axis=2) - lengths).sum(axis=1)
    assert (bound <= moved + left + 1e-9).all()  # rigid (to what the projection left) costs at least the bound
    assert bound.mean() > 0.5 * moved.mean()  # and the bound is not vacuous: within 2x of a real method


def test_frames_solved_in_chunks_give_the_same_bound(shared_data, monkeypatch):
    from streamfix.core import rigid_bound

    m = read_motion(shared_data / "kinect_v2" / "seated_joints.csv")
    observed = np.isfinite(m.positions).all(axis=2) & (m.confidence > 0)
    tracked = observed & (m.confidence >= 1.0)
    whole = least_shift_to_rigid(m.positions, observed, tracked, m.skeleton.bone_array)
    monkeypatch.setattr(rigid_bound, "CHUNK_FRAMES", 37)
    chunked = least_shift_to_rigid(m.positions, observed, tracked, m.skeleton.bone_array)
    np.testing.assert_allclose(chunked, whole, rtol=1e-7, atol=1e-9)
    assert whole.sum() > 0
