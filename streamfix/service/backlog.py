"""Received input waiting for the service loop: bounded by count and age, stamped on arrival.

The ZeroMQ source's receiver thread puts every message here as it leaves the socket; the
service loop takes batches. The overload policy (``shed`` for live sensors, ``block`` for
bulk producers) decides what happens when the loop falls behind.
"""
from __future__ import annotations

import threading
import time
from collections import Counter, deque

__all__ = ["Backlog", "MAX_KEPT_STREAMS"]

MAX_KEPT_STREAMS = 64
"""Streams whose newest frame the age bound keeps (the oldest such frames beyond it are
shed): more than the service runs engines for (``Limits.max_streams``, 16 by default),
and it bounds the receiver's work per message under a flood of stream names."""


class Backlog:
    """Received input waiting for the service loop, bounded by count and age.

    A receiver thread appends every message with its **arrival time** (monotonic ns, as
    soon as it left the socket), so latencies are measured from arrival even while the
    loop is busy. Policy ``shed`` (the default, for live sensors): when more than
    ``max_frames`` frames wait, the oldest are dropped; frames that waited longer than
    ``max_age_s`` are dropped too, except the newest waiting frame of each stream (of up
    to :data:`MAX_KEPT_STREAMS` streams), so the live output stays current: it jumps to the
    latest pose a stream sent rather than to nothing, and the frame carries the count of
    those shed before it (a burst that ends while the loop is busy would otherwise be shed
    whole and never announced). Drops are counted per stream.
    Policy ``block`` (for bulk producers that must lose nothing, e.g. ``replay --rate
    0``): the receiver stops taking messages at ``max_frames``, ZeroMQ's queues fill and
    the producer's PUSH blocks (back-pressure); nothing is shed and latency grows
    instead. Skeleton messages are never shed (they are few and frames need them).
    """

    POLICIES = ("shed", "block")

    def __init__(self, max_frames: int = 2000, max_age_s: float = 0.05, policy: str = "shed") -> None:
        if max_frames < 1 or not max_age_s > 0:
            raise ValueError(f"backlog bounds must be >= 1 frame and > 0 s, got {max_frames}, {max_age_s}")
        if policy not in self.POLICIES:
            raise ValueError(f"overload policy {policy!r}: expected one of {', '.join(self.POLICIES)}")
        self.policy = policy
        self.max_frames = int(max_frames)
        self.max_age_ns = int(max_age_s * 1e9) if policy == "shed" else None
        self._items: deque = deque()  # (parts, arrival_ns, stream or None, is_meta)
        self._waiting: Counter = Counter()  # stream -> its frames in _items
        self._meta: deque = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._woken = False  # wake() since the last take(): it returns at once
        self.shed: Counter = Counter()  # stream (None = unknown) -> frames shed, not yet reported
        self.shed_total = 0

    @staticmethod
    def _stream_of(parts: list) -> tuple[str | None, bool]:
        if len(parts) == 2:
            topic = bytes(parts[0])
            if topic.startswith(b"sf/meta/"):
                return topic[8:].decode("ascii", "replace"), True
            kind, _, stream = topic[3:].partition(b"/")
            return stream.decode("ascii", "replace") or None, False
        return None, False

    def put(self, parts: list, arrival_ns: int) -> None:
        """Append one message (receiver thread); under ``block`` wait while the backlog is full."""
        stream, meta = self._stream_of(parts)
        with self._cond:
            while self.max_age_ns is None and len(self._items) + len(self._meta) >= self.max_frames and not self._closed:
                self._cond.wait(0.1)
            if meta:
                if self.max_age_ns is not None and len(self._meta) >= self.max_frames:  # a flood of them
                    self.shed[self._meta.popleft()[2]] += 1
                    self.shed_total += 1
                self._meta.append((parts, arrival_ns, stream, True))
            else:
                self._items.append((parts, arrival_ns, stream, False))
                self._waiting[stream] += 1
                self._trim(arrival_ns)
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def wake(self) -> None:
        """End a :meth:`take` that waits for input now (or make the next one return at
        once): the service has other work, e.g. clean frames a solver thread finished."""
        with self._cond:
            self._woken = True
            self._cond.notify_all()

    def _trim(self, now_ns: int) -> None:
        """Shed beyond the count bound (oldest first), then what is older than the age
        bound except each stream's newest waiting frame (kept in arrival order)."""
        if self.max_age_ns is None:
            return
        items = self._items
        while len(items) > self.max_frames:
            self._shed_entry(items.popleft())
        newest_kept: deque = deque()
        while items and now_ns - items[0][1] > self.max_age_ns:
            entry = items.popleft()
            if self._waiting[entry[2]] == 1:
                newest_kept.append(entry)
                if len(newest_kept) > MAX_KEPT_STREAMS:
                    self._shed_entry(newest_kept.popleft())
            else:
                self._shed_entry(entry)
        items.extendleft(reversed(newest_kept))

    def _left(self, stream: str | None) -> None:
        """One frame of ``stream`` left the backlog (a name is forgotten at zero: names are untrusted)."""
        self._waiting[stream] -= 1
        if not self._waiting[stream]:
            del self._waiting[stream]

    def _shed_entry(self, entry: tuple) -> None:
        self._left(entry[2])
        self.shed[entry[2]] += 1
        self.shed_total += 1

    def take(self, timeout_s: float, max_n: int) -> tuple[list, dict]:
        """Up to ``max_n`` messages (skeleton messages first) and the shed counts since the last call.

        Each message is ``(parts, arrival_ns, stream, is_meta, newest)``; ``newest``: no later
        frame of its stream is in this batch or still waits."""
        with self._cond:
            if not self._items and not self._meta and timeout_s > 0 and not self._woken:
                self._cond.wait(timeout_s)
            self._woken = False
            self._trim(time.monotonic_ns())
            out = []
            while self._meta and len(out) < max_n:
                out.append(self._meta.popleft())
            while self._items and len(out) < max_n:
                out.append(self._items.popleft())
                self._left(out[-1][2])
            later = set(self._waiting)
            for k in range(len(out) - 1, -1, -1):
                parts, arrival, stream, meta = out[k]
                out[k] = (parts, arrival, stream, meta, stream not in later)
                if not meta:
                    later.add(stream)
            shed, self.shed = dict(self.shed), Counter()
            self._cond.notify_all()  # a blocked receiver may go on
        return out, shed

    def drop_all(self) -> dict:
        """Empty the backlog (shutdown): the counts of what was dropped, per stream."""
        with self._cond:
            for _, _, stream, meta in self._items:
                self.shed[stream] += 1
            self.shed_total += len(self._items)
            self._items.clear()
            self._waiting.clear()
            self._meta.clear()
            shed, self.shed = dict(self.shed), Counter()
        return shed

    def depth(self) -> tuple[int, float]:
        """(frames waiting, age of the oldest in seconds)."""
        with self._cond:
            n = len(self._items) + len(self._meta)
            oldest = self._items[0][1] if self._items else None
        return n, 0.0 if oldest is None else (time.monotonic_ns() - oldest) / 1e9
