"""The paper's corruption protocol: exact fractions, seeded, pure."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.corruption import add_noise, apply_gaps, gap_mask


@pytest.mark.parametrize("fraction", [0.05, 0.1, 0.2, 0.8])
def test_noise_fraction_is_exact_and_bounded(fraction):
    x = np.random.default_rng(1).normal(size=(97, 31, 3))
    y, mask = add_noise(x, fraction, np.random.default_rng(7))
    assert mask.sum() == round(fraction * x.size)
    d = y - x
    assert np.all(d[~mask] == 0)
    assert np.all(np.abs(d[mask]) <= 0.25) and np.abs(d[mask]).max() > 0.2
    # entries are scalar coordinates: corrupted coordinates of one joint-frame are independent
    per_joint = mask.sum(axis=2)
    assert (per_joint == 1).any() and (per_joint == 2).any() or fraction == 0.8


def test_noise_is_seeded_and_pure():
    x = np.zeros((50, 5, 3))
    a, ma = add_noise(x, 0.1, np.random.default_rng(3))
    b, mb = add_noise(x, 0.1, np.random.default_rng(3))
    c, _ = add_noise(x, 0.1, np.random.default_rng(4))
    assert np.array_equal(a, b) and np.array_equal(ma, mb)
    assert not np.array_equal(a, c)
    assert np.all(x == 0)  # input untouched


@pytest.mark.parametrize("fraction", [0.1, 0.2, 0.4])
def test_gap_mask_exact_fraction_and_runs(fraction):
    t, j = 400, 25
    m = gap_mask(t, j, fraction, np.random.default_rng(11))
    assert m.sum() == round(fraction * t * j)
    # runs: most gaps are at least 10 frames long (trimming only shortens the last run,
    # overlaps only merge runs)
    lengths = []
    for col in m.T:
        d = np.diff(np.concatenate([[0], col.astype(int), [0]]))
        starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        lengths += list(stops - starts)
    lengths = np.array(lengths)
    assert (lengths >= 10).mean() > 0.9
    y, obs = apply_gaps(np.ones((t, j, 3)), m)
    assert np.isnan(y[m]).all() and np.array_equal(obs, ~m)
