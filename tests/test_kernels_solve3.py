"""The local quadratic's fallback 3x3 solve (streamfix.core.kernels._solve3_first, rows in
scalars) against the textbook LU loop with partial pivoting it replaces, bit for bit, and
against LAPACK's gesv to rounding."""
from __future__ import annotations

import numpy as np

from streamfix.core import kernels


def _lu_first(m00, m01, m02, m11, m12, m22, b0, b1, b2):
    """First unknown by the textbook loop: pivot = first row of largest magnitude, rows swapped
    whole, elimination by the reciprocal pivot, back substitution column by column."""
    a = np.array([[m00, m01, m02, b0], [m01, m11, m12, b1], [m02, m12, m22, b2]], dtype=np.float64)
    for col in range(3):
        p = col
        for r in range(col + 1, 3):
            if abs(a[r, col]) > abs(a[p, col]):
                p = r
        a[[col, p]] = a[[p, col]]
        inv = 1.0 / a[col, col]
        for r in range(col + 1, 3):
            f = a[r, col] * inv
            a[r, col + 1:] -= f * a[col, col + 1:]
    x2 = a[2, 3] / a[2, 2]
    c1 = a[1, 3] - x2 * a[1, 2]
    c0 = a[0, 3] - x2 * a[0, 2]
    x1 = c1 / a[1, 1]
    c0 -= x1 * a[0, 1]
    return c0 / a[0, 0]


def test_solve3_first_is_the_textbook_lu_bit_for_bit_and_lapacks_to_rounding():
    rng = np.random.default_rng(5)
    pivoted = 0
    for trial in range(3000):
        v = rng.normal(size=9) * 10.0 ** rng.integers(-9, 3, size=9)
        if trial % 3 == 0:  # ties and exact zeros (pivot choice between equal magnitudes)
            v = rng.integers(-2, 3, size=9).astype(float)
        m00, m01, m02, m11, m12, m22 = v[:6]
        M = np.array([[m00, m01, m02], [m01, m11, m12], [m02, m12, m22]])
        if abs(np.linalg.det(M)) < 1e-9 * np.abs(M).max() ** 3:
            continue  # singular: no solution to compare
        pivoted += abs(m01) > abs(m00) or abs(m02) > abs(m00)
        got = kernels._solve3_first(*v)
        assert got == _lu_first(*v)
        ref = np.linalg.solve(M, v[6:])[0]
        assert abs(got - ref) <= 1e-8 * max(1.0, abs(ref)) * np.linalg.cond(M)
    assert pivoted > 500  # the row exchanges were exercised
