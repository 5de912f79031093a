"""The release memory of ``streaming/frozen_release.py``: runs, shifting, and what it releases."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.streaming.frozen_release import ReleaseState, runs_touching, split_state


def test_runs_touching_keeps_whole_runs_with_a_seed_and_nothing_else():
    mask = np.zeros((10, 2), dtype=bool)
    mask[1:4, 0] = mask[6:9, 0] = True  # two runs on joint 0
    mask[2:8, 1] = True
    seeds = np.zeros_like(mask)
    seeds[7, 0] = True  # the second run of joint 0
    seeds[0, 1] = True  # outside joint 1's run: touches nothing
    got = runs_touching(mask, seeds)
    want = np.zeros_like(mask)
    want[6:9, 0] = True
    np.testing.assert_array_equal(got, want)
    assert not runs_touching(mask, np.zeros_like(mask)).any()


class _Inner:
    def __init__(self, shift=0):
        self.shift = shift

    def shifted(self, hop):
        return _Inner(self.shift + hop)


def test_release_state_shifts_its_mask_and_its_inner_state():
    released = np.zeros((6, 2), dtype=bool)
    released[4:, 1] = True
    st = ReleaseState(_Inner(), released)
    assert st.n_frames == 6
    moved = st.shifted(3)
    assert moved.inner.shift == 3
    want = np.zeros_like(released)
    want[1:3, 1] = True
    np.testing.assert_array_equal(moved.released, want)
    assert ReleaseState(None, released).shifted(2).inner is None
    with pytest.raises(ValueError, match="hop must be in 0..6"):
        st.shifted(7)
    assert split_state(st) == (st.inner, released)
    assert split_state("plain")[0] == "plain" and split_state("plain")[1] is None


def test_run_labels_number_each_joints_runs_in_order():
    from streamfix.core.interpolate import run_labels

    mask = np.array([[1, 0], [1, 1], [0, 1], [1, 0]], dtype=bool)
    np.testing.assert_array_equal(run_labels(mask), [[1, 0], [1, 3], [0, 3], [2, 0]])


def test_release_state_reframes_onto_a_window_of_another_length():
    """A stream's first windows grow: the memory maps by frame, the warm start is dropped."""
    released = np.zeros((4, 2), dtype=bool)
    released[1:, 0] = True                      # frames 1..3 of a 4-frame window
    st = ReleaseState(_Inner(), released)
    grown = st.reframed(0, 7)                   # same first frame, 3 frames more
    assert grown.inner is None and grown.n_frames == 7
    want = np.zeros((7, 2), dtype=bool)
    want[1:4, 0] = True
    np.testing.assert_array_equal(grown.released, want)
    later = st.reframed(2, 5)                   # starts 2 frames later
    want = np.zeros((5, 2), dtype=bool)
    want[0:2, 0] = True
    np.testing.assert_array_equal(later.released, want)
    assert not st.reframed(9, 5).released.any()  # no common frame
