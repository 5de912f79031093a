"""The windows' verdict carried onto the ``live`` topic: a limb the solver found broken stays mended.

Why: the live path sees one frame at a time, so it cannot tell a limb the sensor froze, swapped
with its mirror or lost for a second from a limb that really is there; the window solver can
(:mod:`streamfix.streaming.bridging`), but its verdict reaches only the ``clean`` topic, half a
second later. Every solved window ends at the newest frame it was given, so its last frame is
its best guess of *now*. Where the window's real-sensor stages judged a joint's newest samples
wrong (:data:`~streamfix.streaming.solver_api.JUDGED_KEY`: frozen, swapped, jumped, dislocated,
folded) or the sensor has none, and the window puts the joint far from the sample, the live
topic takes the window's pose of that joint, as an offset from its parent in the skeleton tree,
and keeps it while the stream goes on: each carried joint is placed at
``parent + (solved_j - solved_parent)``, parents first, so a carried limb moves with the body
that carries it. A carried joint is let go when the next window no longer finds it off, when
the sensor's own sample comes back within :data:`CARRY_MIN_M` of it (a swap ended, a frozen
limb moves again), or after :data:`CARRY_MAX_S` without a window renewing it; taking and letting
go crossfade over :data:`CROSSFADE_S`.

Pure arrays in, arrays out (metres, seconds). The engine feeds it
(:class:`~streamfix.streaming.engine.StreamEngine`, ``EngineConfig.live_carry``).
"""
from __future__ import annotations

import numpy as np

from ..core import kernels
from ..core.points import finite_points, point_norms

__all__ = ["WindowCarry", "CARRY_MIN_M", "CARRY_MAX_S", "CONFIRM_S", "CROSSFADE_S"]

CARRY_MIN_M = 0.08
"""A window's newest frame must place a joint this far (m) from the sensor's sample of that
frame for the live topic to carry the window's pose of it: above a depth sensor's jitter
(1-3 cm a sample) and a window's own edge error, below the limbs it mends (decimetres)."""
CONFIRM_S = 0.1
"""... on each of the window's newest frames this long (s): a verdict on a window's last frame
or two is its least sure. On KERAAL an arm the sensor had right, flung up 19 cm in one frame,
was an outlier of the window's last two frames only, and holding it there left it far behind."""
CROSSFADE_S = 0.1
"""A joint taken or let go moves between the live path's value and the carried one over this
long (s), linearly: a window's verdict arrives all at once, every hop."""
CARRY_MAX_S = 0.5
"""How long (s) a carried joint is held without a newer window saying it is still off: a
window comes every hop (1/3 s on serve's schedule); one that was skipped or failed must not
leave a stale pose on the topic."""


class WindowCarry:
    """Per body: ``take`` a solved window's newest frame, ``apply`` it to each live frame after.

    ``levels``: the skeleton tree as :func:`streamfix.streaming.live.tree_levels` gives it
    ((parent, child) bones by depth); ``n_joints``; ``rate_hz`` (frames per second).
    """

    def __init__(self, levels: list[np.ndarray], n_joints: int, rate_hz: float) -> None:
        self.parent = np.full(n_joints, -1, dtype=np.intp)
        self.depth = np.zeros(n_joints, dtype=np.intp)  # in the tree: parents before their children
        for d, lv in enumerate(levels, start=1):
            lv = np.asarray(lv, dtype=np.intp)
            self.parent[lv[:, 1]] = lv[:, 0]
            self.depth[lv[:, 1]] = d
        self.order = np.ascontiguousarray(np.argsort(self.depth, kind="stable"), dtype=np.intp)  # parents first
        self.max_frames = max(int(round(CARRY_MAX_S * float(rate_hz))), 1)
        self.confirm_frames = max(int(round(CONFIRM_S * float(rate_hz))), 1)
        self.fade_frames = max(int(round(CROSSFADE_S * float(rate_hz))), 1)
        # the live path's own output of the recent frames (before any carry), by frame number
        self.shown = np.full((self.max_frames + 1, n_joints, 3), np.nan)
        self.shown_frame = np.full(self.max_frames + 1, -1, dtype=np.int64)
        self.reset()

    def reset(self) -> None:
        """Carry nothing, at once."""
        n = len(self.parent)
        self.held = np.zeros(n, dtype=bool)  # joints carried now (their crossfade rises)
        self.level = np.zeros(n, dtype=np.int64)  # frames into each joint's crossfade: its share of
        # the carried pose in the output is level / fade_frames
        self.offset = np.zeros((n, 3))  # from the parent, m (kept while a let-go joint fades out)
        self.age = 0

    def take(self, solved: np.ndarray, raw: np.ndarray, valid: np.ndarray, judged: np.ndarray, frame: int) -> None:
        """A window's newest frames: its solution ``solved`` ``(n, J, 3)`` m, the raw samples ``raw``
        ``(n, J, 3)`` and ``valid`` ``(n, J)`` of those frames, and ``judged`` ``(n, J)``, the
        samples the window's stages judged wrong or the sensor did not give; ``frame`` the number
        of the last of them. Carry the joints the window judged on each of its last
        :data:`CONFIRM_S` worth of frames and placed :data:`CARRY_MIN_M` or more from the sample
        (or gave a value where there is none), and as far from what the live path itself made of
        the last frame (a joint the live path already mended, a spike it gated, is left to it)."""
        n = min(self.confirm_frames, len(solved))
        solved, raw = np.asarray(solved[-n:], dtype=np.float64), np.asarray(raw[-n:], dtype=np.float64)
        seen = np.asarray(valid[-n:], dtype=bool) & finite_points(raw)
        off = point_norms(np.where(seen[..., None], solved - raw, 0.0)) >= CARRY_MIN_M
        held = (np.asarray(judged[-n:], dtype=bool) & (off | ~seen)).all(axis=0) & finite_points(solved[-1])
        solved = solved[-1]
        row = frame % len(self.shown_frame)
        if self.shown_frame[row] == frame:
            own = self.shown[row]
            apart = np.linalg.norm(solved - own, axis=1)
            held &= ~(apart < CARRY_MIN_M)  # NaN (the live path had no value): apart
        p = self.parent
        rooted = p >= 0
        base = np.where(rooted[:, None], solved[np.maximum(p, 0)], np.nan)
        # a joint is placed from its parent (a root, and a joint whose parent the window lacks: not carried)
        held &= rooted & finite_points(base)
        self.held = held
        self.offset = np.where(held[:, None], solved - np.where(np.isfinite(base), base, 0.0), self.offset)
        self.age = 0

    def apply(self, raw: np.ndarray, valid: np.ndarray, live: np.ndarray, recovered: np.ndarray,
              frame: int) -> tuple[np.ndarray, np.ndarray]:
        """The live path's frame ``live`` ``(J, 3)``, number ``frame``, with the carried joints placed
        from their parents, and ``recovered`` ``(J,)`` with them marked; the frame's raw sample
        ``raw`` / ``valid`` lets go of joints the sensor agrees with again. A joint taken or let go
        crossfades over :data:`CROSSFADE_S` (a limb does not jump on the topic when a window's
        verdict arrives). Returns the inputs themselves when nothing is carried."""
        row = frame % len(self.shown_frame)
        self.shown[row] = live
        self.shown_frame[row] = frame
        if not self.level.any() and not self.held.any():
            return live, recovered
        self.age += 1
        if self.age > self.max_frames:  # no window renewed the carry: let go
            self.held[:] = False
        if kernels.COMPILED:  # the same values in one compiled call
            return kernels.live_carry(live, raw, valid, recovered, self.held, self.level, self.offset, self.parent,
                                      self.order, self.fade_frames, CARRY_MIN_M)
        # the few joints carried or fading, parents first (a carried chain follows its carried parent)
        active = np.flatnonzero(self.held | (self.level > 0))
        active = active[np.argsort(self.depth[active], kind="stable")]
        carried = live.copy()
        for c in active.tolist():
            carried[c] = carried[self.parent[c]] + self.offset[c]
        raw_a = raw[active]
        seen = np.asarray(valid, dtype=bool)[active] & finite_points(raw_a)
        near = np.linalg.norm(np.where(seen[:, None], raw_a - carried[active], np.inf), axis=1) < CARRY_MIN_M
        held = self.held[active] & ~(seen & near)  # the sensor has the joint again: its own value from here on
        self.held[active] = held
        level = np.clip(self.level[active] + np.where(held, 1, -1), 0, self.fade_frames)
        self.level[active] = level
        out = live.copy()
        out[active] = live[active] + (level / self.fade_frames)[:, None] * (carried[active] - live[active])
        rec = recovered.copy()
        rec[active] |= level > 0
        return out, rec
