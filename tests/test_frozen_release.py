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


def _bending_arms(T: int, rate_hz: float) -> np.ndarray:
    """A root and two arms (joints 1-3 left elbow/wrist/hand, 4-6 right), 0.3 / 0.25 / 0.08 m,
    bending at 0.5 Hz, the right half a period behind."""
    t = np.arange(T) / rate_hz
    x = np.zeros((T, 7, 3))
    for first, phase in ((1, 0.0), (4, np.pi)):
        ang = 0.8 * np.sin(2 * np.pi * 0.5 * t + phase)
        for k, (length, factor) in enumerate(((0.3, 1.0), (0.25, 2.0), (0.08, 2.0))):
            parent = 0 if k == 0 else first + k - 1
            x[:, first + k] = x[:, parent] + length * np.stack([np.cos(factor * ang), np.sin(factor * ang),
                                                                np.zeros(T)], axis=1)
    return x


def test_a_frozen_run_longer_than_the_tracked_span_is_released_whole_within_one_window():
    """A file's window (here 9 s) can hold a frozen inferred run (6.7 s) whose middle is farther
    than TRACKED_NEAR_S from every tracked sample: it is released whole, not only near its ends."""
    from streamfix.core.inferred import TRACKED_NEAR_S
    from streamfix.streaming.frozen_release import frozen_release

    rate = 30.0
    T, a, b = 270, 30, 230
    x = _bending_arms(T, rate)
    x[a:b, 1:4] = x[a - 1, 1:4][None]  # the left arm stops bending: the sensor's frozen guess
    conf = np.ones((T, 7))
    conf[a:b, 1:4] = 0.5  # flagged inferred
    bones = np.array([[0, 1], [1, 2], [2, 3], [0, 4], [4, 5], [5, 6]])
    layout = (np.array([False, True, True, True, True, True, True]), np.array([0, 4, 5, 6, 1, 2, 3]))
    far = (a + int(TRACKED_NEAR_S[1] * rate) + 5, b - int(TRACKED_NEAR_S[1] * rate) - 5)
    assert far[0] < far[1]  # frames no tracked sample of the arm is near
    got = frozen_release(x, conf, bones, rate, layout)
    assert got[a:b, 1:4].all()
    assert not got[:a].any() and not got[b:].any() and not got[:, 4:].any()
    held_still = x.copy()  # both arms still: a person holding still, nothing released
    held_still[:, 4:] = held_still[0, 4:][None]
    assert not frozen_release(held_still, conf, bones, rate, layout).any()
