"""Left/right limb swaps undone in the engine's windows (core/swaps.py, streaming/swaps.py),
on real mocap retargeted to Kinect v2 joints."""
import numpy as np
import pytest

from streamfix.core.swaps import undo_limb_swaps
from streamfix.limbs import limb_groups
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.swaps import unswap_window

RATE = 30.0


@pytest.fixture(scope="module")
def walk(shared_data):
    from streamfix.evaluation.sensor import ground_truth

    return ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", RATE).positions


def _legs():
    knee = KINECT_V2.joint_names.index("KneeLeft")
    return next((a, b) for a, b in limb_groups(KINECT_V2) if knee in a or knee in b)


def _swapped(x, frames, pair):
    a, b = pair
    out = x.copy()
    out[frames[:, None], np.concatenate([a, b])[None, :]] = x[frames[:, None], np.concatenate([b, a])[None, :]]
    return out


def test_a_swap_inside_a_window_is_exchanged_back(walk):
    legs = _legs()
    frames = np.arange(83, 94)
    raw = _swapped(walk, frames, legs)
    fixed, mask = undo_limb_swaps(raw[40:120], list(limb_groups(KINECT_V2)), RATE)
    assert np.array_equal(np.flatnonzero(mask.any(axis=1)) + 40, frames)
    np.testing.assert_allclose(fixed, walk[40:120], atol=1e-12)


def test_a_swap_that_began_before_the_window_ends_where_it_ends_despite_a_joint_missing_from_the_history(walk):
    """The window [41, 101) starts inside a swap of frames 31-45 and holds another, 83-93.
    Its clean history (frames before 41, already unswapped) lacks one leg joint on the two
    frames before the window, as when the engine flagged it recovered: the toggle into the
    swapped labelling at frame 41 must still be seen (it was not, and the window swapped
    back frames 94-100 instead of 83-93)."""
    legs = _legs()
    raw = _swapped(_swapped(walk, np.arange(31, 46), legs), np.arange(83, 94), legs)
    history = walk[:41].copy()
    history[-2:, legs[0][-1]] = np.nan
    window = raw[41:101]
    fixed, mask = unswap_window(window, np.ones(window.shape[:2], dtype=bool), KINECT_V2, RATE, history)
    swapped_frames = np.flatnonzero(mask.any(axis=1)) + 41
    assert np.array_equal(swapped_frames, np.r_[41:46, 83:94])
    np.testing.assert_allclose(fixed, walk[41:101], atol=1e-12)


def test_a_swap_from_the_second_frame_is_seen_beginning(walk):
    """A take whose second frame already has its legs exchanged (Xia depressed_13_000,
    seed 0, was left swapped: the toggle into the swap had no two frames before it)."""
    legs = _legs()
    frames = np.arange(1, 11)
    raw = _swapped(walk[:48], frames, legs)
    fixed, mask = undo_limb_swaps(raw, list(limb_groups(KINECT_V2)), RATE)
    assert np.array_equal(np.flatnonzero(mask.any(axis=1)), frames)
    np.testing.assert_allclose(fixed, walk[:48], atol=1e-12)
