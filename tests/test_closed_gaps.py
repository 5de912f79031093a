"""Overlap-add of gap fills: once a window has seen a gap end, the fills older windows made
while it was open (extrapolations) no longer count (streamfix.streaming.overlap_add)."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.interpolate import interpolate_spline
from streamfix.evaluation.long_gaps import _engine
from streamfix.io import read_motion
from streamfix.streaming.overlap_add import closed_gaps


def test_closed_gaps_are_the_missing_samples_seen_again_later():
    valid = np.array([[1, 1], [0, 1], [0, 0], [1, 0], [0, 0]], dtype=bool)
    expected = np.array([[0, 0], [1, 0], [1, 0], [0, 0], [0, 0]], dtype=bool)
    np.testing.assert_array_equal(closed_gaps(valid), expected)
    assert not closed_gaps(np.zeros((4, 3), dtype=bool)).any()          # never seen: nothing to close
    assert not closed_gaps(np.ones((4, 3), dtype=bool)).any()           # nothing missing


@pytest.fixture(scope="module")
def take_85(shared_data):
    return read_motion(shared_data / "c3d" / "85_02.c3d")


def test_serve_fills_a_blackout_shorter_than_its_lookahead_from_both_ends(take_85):
    """0.3 s whole-frame blackouts in a 120 Hz marker take, ``serve``'s schedule (0.5 s
    lookahead): every blackout frame is emitted after a window saw the blackout end, and
    its value is that window's (the spline through both ends), not a blend with the
    earlier windows' extrapolations (1.6x the spline's error before)."""
    x = take_85.positions
    ctx = {"skeleton": take_85.skeleton, "rate_hz": take_85.rate_hz}
    serve, spline = [], []
    for a in (150, 400, 650):
        obs = np.ones(x.shape[:2], dtype=bool)
        obs[a:a + 36] = False
        xin = np.where(obs[..., None], x, np.nan)
        serve.append(np.linalg.norm(_engine(serve=True)(xin, obs, ctx)[~obs] - x[~obs], axis=1).mean())
        spline.append(np.linalg.norm(interpolate_spline(xin, obs)[0][~obs] - x[~obs], axis=1).mean())
    assert np.mean(serve) <= 1.05 * np.mean(spline), (serve, spline)
