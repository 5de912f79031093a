"""streamfix.core.points: the xyz reductions give numpy's own values (the norm bit for bit)."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.points import all_xyz, any_xyz, finite_points, point_dots, point_norms


def test_point_norms_equal_numpy_norm_bit_for_bit_with_missing_and_infinite_points():
    rng = np.random.default_rng(3)
    v = rng.normal(scale=0.7, size=(200, 25, 3))
    v[5, 3, 1] = np.nan
    v[7, 2] = np.inf
    v[9, 4, 2] = -np.inf
    assert np.array_equal(point_norms(v), np.linalg.norm(v, axis=-1), equal_nan=True)
    assert np.array_equal(point_norms(v[0]), np.linalg.norm(v[0], axis=1))
    assert point_norms(np.array([3.0, 4.0, 12.0])) == 13.0


def test_masks_reduce_the_xyz_axis_like_all_and_any():
    rng = np.random.default_rng(4)
    m = rng.random((50, 17, 3)) < 0.5
    assert np.array_equal(all_xyz(m), m.all(axis=-1))
    assert np.array_equal(any_xyz(m), m.any(axis=-1))
    x = rng.normal(size=(50, 17, 3))
    x[m] = np.nan
    x[3, 3, 0] = np.inf
    assert np.array_equal(finite_points(x), np.isfinite(x).all(axis=-1))


@pytest.mark.parametrize("shape", [(10, 4), (3,) * 0, (5, 3, 2)])
def test_arrays_that_are_not_points_are_refused_with_their_shape(shape):
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        point_norms(np.zeros(shape))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        all_xyz(np.zeros(shape, dtype=bool))


def test_point_dots_equal_the_summed_products_bit_for_bit_and_broadcast():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(40, 6, 3))
    b = rng.normal(size=(40, 6, 3))
    a[2, 2, 1] = np.nan
    assert np.array_equal(point_dots(a, b), (a * b).sum(axis=-1), equal_nan=True)
    assert np.array_equal(point_dots(a, b[0]), (a * b[0]).sum(axis=-1), equal_nan=True)
