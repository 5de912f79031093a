"""Which frozen inferred samples a window releases, and the memory that carries a release on.

Why: :func:`streamfix.core.frozen.frozen_inferred` finds an inferred limb that stopped
bending; a window releases such samples (makes them missing, for the gap fill) near a
tracked sample of the same joint, where the fill has an anchor (``TRACKED_NEAR_S``). A
sensor that loses a limb for longer than a window (2 s at 30 Hz) then showed no tracked
sample to the windows inside the loss, and they handed the frozen guess back mid-run: the
limb snapped from the fill to the sensor's frozen pose and back. The windows of a body are
solved in order, each warm-started from the one before (the engine shifts the state by
the hop), so the release rides along in that state: :class:`ReleaseState` holds the
samples the previous window released, and a frozen run that contains one of them goes on
being released to its end (while it stays rigid; the twin test is not asked again); the
memory also crosses a stream's first windows, which grow frame by frame and get no warm
start (:meth:`ReleaseState.reframed`: a limb frozen from the stream's start was handed back
a second in). A run never released near a tracked sample (a seated person's legs under a
desk, inferred for minutes) is still left alone: with no tracked sample to anchor it, the
fill guesses worse (on ``seated_joints.csv``, before the twin test, releasing the legs for
4 s made them jitter more than median + Savitzky-Golay's). The memory is the solver's own, not the
clean history's recovered samples: those also come from foot support's planted legs, and
continuing from them released the seated right leg and moved its ankle far from the
sensor's guess.

Arrays: positions ``(T, J, 3)`` metres, masks ``(T, J)`` bool.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.excursion import parents_from_bones
from ..core.frozen import frozen_and_rigid
from ..core.inferred import tracked_proximity
from ..core.interpolate import run_labels
from ..skeletons import Skeleton

__all__ = ["ReleaseState", "split_state", "frozen_release", "runs_touching", "limb_layout"]


@dataclass(frozen=True)
class ReleaseState:
    """A window solver's warm start (``inner``, any object or None) and the samples its
    window released as frozen (``released``, ``(T, J)`` bool), shifted with it."""

    inner: Any
    released: np.ndarray

    @property
    def n_frames(self) -> int:
        return int(self.released.shape[0])

    def shifted(self, hop: int) -> "ReleaseState":
        """The state for the window ``hop`` frames later (same length): the inner state
        shifted, the released samples moved back by ``hop`` (new frames: none released)."""
        hop = int(hop)
        T = self.n_frames
        if not 0 <= hop <= T:
            raise ValueError(f"hop must be in 0..{T} frames, got {hop}")
        inner = self.inner
        if inner is not None and hasattr(inner, "shifted"):
            inner = inner.shifted(hop)
        return ReleaseState(inner, self.reframed(hop, T).released)

    def reframed(self, offset: int, n_frames: int) -> "ReleaseState":
        """The release memory for a window of ``n_frames`` frames starting ``offset`` frames
        after this one's first frame, whatever the two windows' lengths (a stream's first
        windows grow frame by frame until they reach the full length); the warm start is
        dropped (it needs windows of one length). Frames outside this window: none released."""
        offset, n_frames = int(offset), int(n_frames)
        released = np.zeros((n_frames,) + self.released.shape[1:], dtype=bool)
        lo, hi = max(0, offset), min(self.n_frames, offset + n_frames)
        if lo < hi:
            released[lo - offset:hi - offset] = self.released[lo:hi]
        return ReleaseState(None, released)


def split_state(state: Any) -> tuple[Any, np.ndarray | None]:
    """``(inner warm start, released samples or None)`` of whatever state the engine passed."""
    if isinstance(state, ReleaseState):
        return state.inner, state.released
    return state, None


def runs_touching(mask: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """``(T, J)`` bool: the runs of ``mask`` (consecutive True samples of one joint) that
    contain at least one sample of ``seeds``."""
    m = np.asarray(mask, dtype=bool)
    label = run_labels(m)
    hit = np.unique(label[m & np.asarray(seeds, dtype=bool)])
    return np.isin(label, hit[hit > 0])


def limb_layout(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """``((J,) bool, (J,) int)``: the joints below a limb's root (their pose relative to
    the parent changes as the person moves) and each joint's left/right twin."""
    from ..limbs import limb_groups, mirror_index

    parents = parents_from_bones(skeleton.bone_array, skeleton.n_joints)
    limbs = np.zeros(skeleton.n_joints, dtype=bool)
    for pair in limb_groups(skeleton):
        for side in pair:
            limbs[side] = True
    limbs &= (parents >= 0) & limbs[np.maximum(parents, 0)]
    return limbs, mirror_index(skeleton)


def frozen_release(
    positions: np.ndarray,
    confidence: np.ndarray,
    bones: np.ndarray,
    rate_hz: float,
    layout: tuple[np.ndarray, np.ndarray],
    released_before: np.ndarray | None = None,
) -> np.ndarray:
    """``(T, J)`` bool: the inferred samples of a frozen or drifting limb
    (:func:`streamfix.core.frozen.frozen_inferred`) that the window releases: those near a
    tracked sample of the joint (:func:`streamfix.core.inferred.tracked_proximity`), and
    whole rigid inferred runs (the twin not asked again) that contain one of those or a sample
    the previous window released (``released_before``, already shifted to this window's frames)."""
    conf = np.asarray(confidence, dtype=np.float64)
    inferred = (conf > 0) & (conf < 1.0)
    if not inferred.any():
        return np.zeros(conf.shape, dtype=bool)
    limbs, mirror = layout
    x = np.asarray(positions, dtype=np.float64)
    parents = parents_from_bones(bones, x.shape[1])
    frozen, rigid = frozen_and_rigid(x, inferred, parents, limbs, rate_hz, mirror=mirror)
    release = frozen & (tracked_proximity(conf >= 1.0, rate_hz) > 0)
    seeds = release
    if released_before is not None and released_before.shape == frozen.shape and released_before.any():
        # a run already judged a guess stays one while it stays rigid, whether or not the
        # twin still bends (the twin test tells a guess from a limb held still at its start)
        seeds = release | released_before
    # and so does a run released here near a tracked sample, to its end, also where it lies
    # farther than TRACKED_NEAR_S from every tracked sample (a file's window holding a frozen
    # run longer than twice that span handed its middle back to the sensor's guess, which a
    # stream's windows reach through the memory)
    if seeds.any():
        release = release | runs_touching(rigid, seeds)
    return release
