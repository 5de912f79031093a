"""Per-body ring buffer of the last W frames, readable as one contiguous window.

The buffer stores ``2W`` rows and writes every frame twice, at ``i`` and ``i + W``
(``i = count mod W``). The last ``W`` frames are then always the contiguous slice
``[i + 1, i + 1 + W)`` of the doubled storage, so :meth:`RingBuffer.window` returns
a numpy *view* (no copy, no concatenation) in O(1) and a push costs two row writes:
no Python loop over joints or frames anywhere.

Units: positions metres ``(J, 3)``, confidence in [0, 1] ``(J,)``, timestamps
integer nanoseconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.points import finite_points

__all__ = ["RingBuffer", "RingWindow"]


@dataclass
class RingWindow:
    """Views of ``n`` consecutive frames ending at frame index ``end`` (exclusive).

    ``start``/``end`` are absolute frame indices (frames pushed since creation).
    The arrays are views into the ring: copy them before the ring is pushed again
    if they must outlive the next push (e.g. when handed to another thread).
    """

    start: int
    end: int
    positions: np.ndarray  # (n, J, 3) metres, NaN where missing
    confidence: np.ndarray  # (n, J)
    valid: np.ndarray  # (n, J) bool, True = observed
    time_ns: np.ndarray  # (n,) int64

    def copy(self) -> "RingWindow":
        return RingWindow(
            self.start,
            self.end,
            self.positions.copy(),
            self.confidence.copy(),
            self.valid.copy(),
            self.time_ns.copy(),
        )


class RingBuffer:
    """Sliding window of the last ``capacity`` frames of one body.

    Each row holds one observation: positions, confidence, validity, sensor time.
    """

    def __init__(self, capacity: int, n_joints: int) -> None:
        if capacity < 1:
            raise ValueError(f"ring capacity must be >= 1 frame, got {capacity}")
        if n_joints < 1:
            raise ValueError(f"ring needs >= 1 joint, got {n_joints}")
        self.capacity = int(capacity)
        self.n_joints = int(n_joints)
        w2 = 2 * self.capacity
        self._pos = np.full((w2, n_joints, 3), np.nan)
        self._conf = np.zeros((w2, n_joints))
        self._valid = np.zeros((w2, n_joints), dtype=bool)
        self._time = np.zeros(w2, dtype=np.int64)
        self.count = 0  # frames pushed so far (absolute index of the next frame)

    def __len__(self) -> int:
        return min(self.count, self.capacity)

    def push(self, positions: np.ndarray, confidence: np.ndarray, time_ns: int) -> int:
        """Append one frame; returns its absolute index. NaN or conf <= 0 is missing."""
        i = self.count % self.capacity
        j = i + self.capacity
        pos = self._pos
        pos[i] = positions
        valid = (np.asarray(confidence) > 0) & finite_points(pos[i])
        if valid.all():  # the usual frame: nothing to blank
            pos[j] = pos[i]
            self._conf[i] = self._conf[j] = confidence
        else:
            pos[i][~valid] = np.nan
            pos[j] = pos[i]
            self._conf[i] = self._conf[j] = np.where(valid, confidence, 0.0)
        self._valid[i] = self._valid[j] = valid
        self._time[i] = self._time[j] = time_ns
        self.count += 1
        return self.count - 1

    def push_many(self, positions: np.ndarray, confidence: np.ndarray,
                  time_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Append ``n`` frames at once (``(n, J, 3)``, ``(n, J)``, ``(n,)``): the same rows as
        :meth:`push` on each in turn. Returns the frames as stored (positions NaN and
        confidence 0 where missing, and the valid mask), all ``n`` of them."""
        valid = (np.asarray(confidence) > 0) & finite_points(positions)
        pos = np.where(valid[..., None], positions, np.nan)
        conf = np.where(valid, confidence, 0.0)
        stored = (pos, conf, valid)
        n = len(positions)
        cap = self.capacity
        if n > cap:  # the older ones would be overwritten within this call
            self.count += n - cap
            pos, conf, valid, time_ns = pos[n - cap:], conf[n - cap:], valid[n - cap:], time_ns[n - cap:]
            n = cap
        if n == 0:
            return stored
        first = self.count % cap
        for lo in (first, first + cap):  # each frame twice (module doc); a run may wrap past 2 cap
            head = min(n, 2 * cap - lo)
            self._pos[lo:lo + head], self._conf[lo:lo + head] = pos[:head], conf[:head]
            self._valid[lo:lo + head], self._time[lo:lo + head] = valid[:head], time_ns[:head]
            if head < n:  # the rest wraps to the start of the storage
                rest = n - head
                self._pos[:rest], self._conf[:rest] = pos[head:], conf[head:]
                self._valid[:rest], self._time[:rest] = valid[head:], time_ns[head:]
        self.count += n
        return stored

    def push_missing(self, time_ns: int) -> int:
        """Append a frame in which every joint is missing (absent body, dropped frame)."""
        i = self.count % self.capacity
        j = i + self.capacity
        self._pos[i] = self._pos[j] = np.nan
        self._conf[i] = self._conf[j] = 0.0
        self._valid[i] = self._valid[j] = False
        self._time[i] = self._time[j] = time_ns
        self.count += 1
        return self.count - 1

    def _row(self, index: int) -> int:
        if not (self.count - len(self) <= index < self.count):
            raise IndexError(
                f"frame {index} is not in the ring (holds frames {self.count - len(self)}..{self.count - 1})"
            )
        return index % self.capacity

    def frame(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions, confidence, valid) views of frame ``index`` (absolute)."""
        i = self._row(index)
        return self._pos[i], self._conf[i], self._valid[i]

    def window(self, n: int | None = None, end: int | None = None) -> RingWindow:
        """Views of the last ``n`` frames ending at absolute index ``end`` (exclusive).

        ``end`` defaults to the newest frame + 1; ``n`` is clipped to what the ring
        still holds before ``end`` (so a window ending early is shorter).
        """
        end = self.count if end is None else int(end)
        if not (0 <= end <= self.count):
            raise IndexError(f"window end {end} outside 0..{self.count}")
        oldest = self.count - len(self)
        n = self.capacity if n is None else int(n)
        start = max(end - n, oldest, 0)
        if end <= start:
            start = end
        # Row of absolute frame k in the doubled storage, picking the copy such that
        # [start, end) is contiguous: the newest frame (count-1) sits at row
        # (count-1) % W + W, and earlier frames follow it backwards.
        top = (self.count - 1) % self.capacity + self.capacity if self.count else self.capacity
        hi = top - (self.count - end) + 1
        lo = hi - (end - start)
        sl = slice(lo, hi)
        return RingWindow(
            start, end, self._pos[sl], self._conf[sl], self._valid[sl], self._time[sl]
        )

    def recent_positions(self, n: int) -> np.ndarray:
        """View ``(min(n, len), J, 3)`` of the newest frames' positions (oldest first)."""
        return self.window(n).positions
