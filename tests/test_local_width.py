"""The per-frame half-width choice (streamfix.core.local_width): its pieces on small arrays."""
from __future__ import annotations

import numpy as np

from streamfix.core.isometry import bone_length_deviations
from streamfix.core.local_width import frame_bone_deviation, local_width_index, take_fractional


def test_frame_bone_deviation_counts_the_bones_the_window_score_counts():
    rng = np.random.default_rng(1)
    x = rng.normal(scale=0.3, size=(40, 4, 3))
    bones = np.array([[0, 1], [1, 2], [2, 3]])
    x[:, 3] = x[:, 2]  # a zero-length bone: not counted (as bone_length_deviations)
    observed = np.ones((40, 4), dtype=bool)
    observed[10:15, 0] = False  # bone 0 unseen there
    sums, counts = frame_bone_deviation(x, observed, bones, 0.02)
    assert counts[12] == 1 and counts[0] == 2
    one = np.array([[1, 2]])
    s1, _ = frame_bone_deviation(x, observed, one, 0.02)
    lengths = np.linalg.norm(x[:, 2] - x[:, 1], axis=1)
    np.testing.assert_allclose(s1, np.abs(lengths - np.median(lengths)))
    # the window's score is the median of these per-frame deviations
    assert np.isclose(np.median(s1), bone_length_deviations(x, observed, one, 0.02)[0])


def test_local_width_index_takes_the_locally_best_candidate_smoothly():
    T = 60
    sums = np.ones((3, T))
    sums[2, :30] = 0.1   # the widest candidate is best in the first half
    sums[0, 30:] = 0.1   # the shortest in the second
    counts = np.ones((3, T))
    hard = local_width_index(sums, counts, 2, 0)
    assert (hard[:28] == 2).all() and (hard[32:] == 0).all()
    soft = local_width_index(sums, counts, 2, 3)
    assert (np.abs(np.diff(soft)) <= 2 / 7 + 1e-12).all()  # moves one candidate per 3.5 frames at most
    assert np.isclose(soft[0], 2) and np.isclose(soft[-1], 0)
    # ties go to the shortest; frames with no bone near them take candidate 0
    assert (local_width_index(np.ones((3, T)), counts, 2, 0) == 0).all()
    assert (local_width_index(sums, np.zeros((3, T)), 2, 0) == 0).all()


def test_take_fractional_interpolates_between_neighbouring_candidates():
    stack = np.arange(3.0)[:, None, None] * np.ones((3, 4, 2))  # candidate k holds k
    out = take_fractional(stack, np.array([0.0, 0.5, 1.25, 2.0]))
    np.testing.assert_allclose(out[:, 0], [0.0, 0.5, 1.25, 2.0])
    assert out.shape == (4, 2)


def test_the_compiled_spread_gives_the_reference_per_frame_sums_bit_for_bit():
    """clean_window scores each candidate from one pass over its bone lengths
    (kernels.bone_spread_deviations with frames=True): the same window score and per-frame
    sums, bit for bit, as the numpy references it replaces."""
    import pytest

    from streamfix.core import kernels
    from streamfix.core.local_width import frame_sums

    if not kernels.COMPILED:
        pytest.skip("numba not available")
    rng = np.random.default_rng(4)
    x = rng.normal(scale=0.3, size=(90, 6, 3))
    x[:, 5] = x[:, 4] + 0.001  # a bone below the minimum length: NaN, not counted
    bones = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [0, 3], [1, 4], [2, 5], [0, 5]])
    observed = rng.random((90, 6)) > 0.1
    observed[:, 2] = False  # bones never seen
    dev, per_frame = kernels.bone_spread_deviations(x, observed, bones, 0.02, frames=True)
    lengths = np.where(observed[:, bones[:, 0]] & observed[:, bones[:, 1]],
                       np.linalg.norm(x[:, bones[:, 1]] - x[:, bones[:, 0]], axis=2), np.nan)
    seen = np.isfinite(lengths).any(axis=0)
    typical = np.full(len(bones), np.nan)
    typical[seen] = np.nanmedian(lengths[:, seen], axis=0)
    counted = typical > 0.02
    assert counted.sum() == 5  # the bones that count: neither unseen nor too short
    ref_dev = np.full(len(bones), np.nan)
    ref_dev[counted] = np.nanmedian(np.abs(lengths - typical)[:, counted], axis=0)
    np.testing.assert_array_equal(dev, ref_dev)
    sums, counts = frame_sums(per_frame, np.isfinite(dev))
    ref_sums, ref_counts = frame_bone_deviation(x, observed, bones, 0.02)
    np.testing.assert_array_equal(sums, ref_sums)
    np.testing.assert_array_equal(counts, ref_counts)
