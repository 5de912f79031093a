"""The sort-based NaN median against numpy's."""
from __future__ import annotations

import warnings

import numpy as np

from streamfix.core.robust_stats import nanmedian


def test_nanmedian_equals_numpys_on_every_axis_and_gap_pattern():
    rng = np.random.default_rng(1)
    for _ in range(200):
        shape = tuple(int(n) for n in rng.integers(1, 9, size=int(rng.integers(1, 4))))
        values = rng.normal(size=shape)
        values[rng.random(shape) < rng.uniform(0, 1)] = np.nan  # from none to every sample missing
        axis = int(rng.integers(0, len(shape)))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN slice: NaN
            want = np.nanmedian(values, axis=axis)
        np.testing.assert_allclose(nanmedian(values, axis=axis), want, equal_nan=True, rtol=0, atol=1e-15)
