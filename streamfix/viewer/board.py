"""The viewer's frame board: raw and cleaned frames of one instant, the newest few only.

The service sends ``raw`` and ``live`` frames at once and ``clean`` frames a fixed
lookahead later (0.5 s by default). To show raw versus clean *of the same instant*
the board holds each stream's recent raw/live frames for a few seconds, keyed by
sensor time, and pairs each arriving ``clean`` frame with them (SPEC section 2: the
three topics carry the same ``t_sensor_ns`` for one instant). A clean frame whose
raw partner never arrived is shown without it.

Never a backlog: the board keeps only the **newest ``keep`` paired instants per stream**
(a few frames). A reader (one per browser connection) remembers how many instants of
each stream it has taken; instants pushed out before a reader took them are *dropped*
for that reader and counted. So what a reader has pending is at most ``keep`` records
per stream however slow it is, and the held raw frames are bounded by ``hold_s`` x the
stream rate. Why a few and not only the newest: the service emits ``clean`` frames a
window hop at a time (several in the same millisecond); with newest-only even an idle
page would miss most of each burst, and its rolling plots would be decimated. The page
plays the few it gets at their sensor timing (see ``static/viewer.js``).
"""
from __future__ import annotations

import threading
import time
from collections import Counter, OrderedDict, deque
from dataclasses import dataclass, field

import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..skeletons import Skeleton

__all__ = ["FrameBoard", "BoardReader", "body_json"]

_HELD_MAX = 4096  # raw/live instants held per stream, whatever the rate (memory bound)


def _joints_json(positions: np.ndarray) -> list:
    """``(J, 3)`` metres -> list of ``[x, y, z]`` rounded to 0.1 mm, ``None`` where missing."""
    rows = np.round(np.asarray(positions, dtype=np.float64), 4)
    ok = np.isfinite(rows).all(axis=1)
    out = rows.tolist()
    for j in np.flatnonzero(~ok):
        out[j] = None
    return out


def body_json(raw: BodyFrame | None, clean: BodyFrame | None, live: BodyFrame | None = None) -> dict:
    """One body of one instant as the page draws it: raw, live and clean joints, recovered flags."""
    some = clean or raw or live
    rec = None
    if clean is not None and clean.recovered is not None:
        rec = np.asarray(clean.recovered, dtype=np.uint8).tolist()
    return {
        "id": int(some.body_id),
        "raw": None if raw is None else _joints_json(raw.positions),
        "live": None if live is None else _joints_json(live.positions),
        "clean": None if clean is None else _joints_json(clean.positions),
        "rec": rec,
    }


def _ms(a_ns: int, b_ns: int) -> float | None:
    """``a - b`` in milliseconds when both wall-clock stamps are known."""
    if a_ns <= 0 or b_ns <= 0:
        return None
    return round((a_ns - b_ns) / 1e6, 3)


@dataclass
class _Held:
    raw: SkeletonFrame | None = None
    live: SkeletonFrame | None = None


@dataclass
class _Stream:
    held: "OrderedDict[int, _Held]" = field(default_factory=OrderedDict)
    count: int = 0           # instants published on the board
    records: deque = field(default_factory=deque)  # (instant number, record), the newest `keep`


class FrameBoard:
    """Pairs raw/live/clean frames by instant and keeps the newest few pairs per stream.

    ``hold_s``: seconds of raw/live frames held while their clean partner is due
    (longer than the service's lookahead plus its compute time). ``keep``: paired
    instants kept per stream for readers (the bound on what a reader can have pending).
    ``counters``: frames ingested per kind, ``paired`` / ``unpaired`` clean frames,
    ``expired`` raw instants that never met a clean frame.
    """

    def __init__(self, hold_s: float = 5.0, keep: int = 8) -> None:
        if not hold_s > 0:
            raise ValueError(f"hold_s must be > 0 seconds, got {hold_s}")
        if keep < 1:
            raise ValueError(f"keep must be >= 1 record per stream, got {keep}")
        self.hold_ns = int(hold_s * 1e9)
        self.keep = int(keep)
        self.counters: Counter = Counter()
        self.layouts: dict[str, dict] = {}  # stream -> {"skeleton", "joint_names", "bones", "rate_hz"}
        self._streams: dict[str, _Stream] = {}
        self._cond = threading.Condition()

    # ------------------------------------------------------------------ writers
    def set_layout(self, stream: str, skeleton: Skeleton, rate_hz: float | None = None) -> None:
        """Remember a stream's joint names and bones (sent once to each page)."""
        with self._cond:
            self.layouts[stream] = {
                "skeleton": skeleton.name,
                "joint_names": list(skeleton.joint_names),
                "bones": [list(b) for b in skeleton.bones],
                "rate_hz": None if rate_hz is None else float(rate_hz),
            }

    def ingest(self, kind: str, frame: SkeletonFrame, recv_time_ns: int | None = None) -> None:
        """Take one frame of topic ``kind`` (``raw``, ``live`` or ``clean``)."""
        recv = time.time_ns() if recv_time_ns is None else int(recv_time_ns)
        with self._cond:
            self.counters[kind] += 1
            st = self._streams.get(frame.stream_id)
            if st is None:
                st = self._streams[frame.stream_id] = _Stream(records=deque(maxlen=self.keep))
            t = int(frame.sensor_time_ns)
            if kind in ("raw", "live"):
                held = st.held.get(t)
                if held is None:
                    held = st.held[t] = _Held()
                setattr(held, kind, frame)
                self._expire(st, t)
                return
            if kind != "clean":
                raise ValueError(f"frame kind must be raw, live or clean, got {kind!r}")
            held = st.held.pop(t, None) or _Held()
            self.counters["paired" if held.raw is not None else "unpaired"] += 1
            st.count += 1
            st.records.append((st.count, self._record(frame, held, recv)))
            self._cond.notify_all()

    def _expire(self, st: _Stream, newest_t: int) -> None:
        while st.held:
            t = next(iter(st.held))
            if newest_t - t <= self.hold_ns and len(st.held) <= _HELD_MAX:
                break
            st.held.popitem(last=False)
            self.counters["expired"] += 1

    @staticmethod
    def _record(clean: SkeletonFrame, held: _Held, recv_ns: int) -> dict:
        raw_b = {b.body_id: b for b in held.raw.bodies} if held.raw is not None else {}
        live_b = {b.body_id: b for b in held.live.bodies} if held.live is not None else {}
        bodies = [body_json(raw_b.pop(b.body_id, None), b, live_b.get(b.body_id)) for b in clean.bodies]
        bodies += [body_json(b, None, live_b.get(b.body_id)) for b in raw_b.values()]  # raw bodies the cleaner dropped
        raw_pub = held.raw.publish_time_ns if held.raw is not None else 0
        live_pub = held.live.publish_time_ns if held.live is not None else 0
        return {
            "stream": clean.stream_id,
            "seq": int(clean.seq),
            "t": clean.sensor_time_ns / 1e9,
            "skeleton": clean.skeleton,
            "filled": bool(clean.filled),
            "t_publish_ms": clean.publish_time_ns / 1e6 if clean.publish_time_ns > 0 else None,  # wall clock
            "bodies": bodies,
            "latency_ms": {  # wall-clock stamps of the service: delays it added, and the wire's
                "live": _ms(live_pub, raw_pub),
                "clean": _ms(clean.publish_time_ns, raw_pub),
                "wire": _ms(recv_ns, clean.publish_time_ns),
            },
        }

    # ------------------------------------------------------------------ readers
    def reader(self) -> "BoardReader":
        return BoardReader(self)

    def _take(self, seen: dict[str, int], timeout_s: float) -> tuple[list[dict], int, int]:
        deadline = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while True:
                fresh = [(s, st) for s, st in self._streams.items() if st.count > seen.get(s, 0)]
                if fresh:
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return [], 0, 0
                self._cond.wait(remaining)
            out: list[dict] = []
            dropped = 0
            for s, st in fresh:
                new = [rec for n, rec in st.records if n > seen.get(s, 0)]
                dropped += st.count - seen.get(s, 0) - len(new)
                seen[s] = st.count
                out += new
            return out, dropped, len(out)

    def counts(self) -> dict[str, int]:
        """Instants published so far per stream (a new reader starts from these)."""
        with self._cond:
            return {s: st.count for s, st in self._streams.items()}

    def held_frames(self) -> int:
        """Raw/live instants held while waiting for their clean partner (all streams)."""
        with self._cond:
            return sum(len(st.held) for st in self._streams.values())


class BoardReader:
    """One consumer's view of a :class:`FrameBoard` (one per browser connection).

    :meth:`take` returns the records this reader has not taken yet, oldest first per
    stream (at most the board's ``keep`` per stream), counts those pushed out before it
    took them (``dropped``) and how many it got (``queue``: never more than ``keep`` x
    the number of streams).
    """

    def __init__(self, board: FrameBoard) -> None:
        self.board = board
        self.seen: dict[str, int] = board.counts()  # what came before this reader joined is not "dropped"
        self.dropped = 0
        self.taken = 0
        self.max_queue = 0
        self.last_queue = 0

    def take(self, timeout_s: float = 0.1) -> list[dict]:
        records, dropped, queue = self.board._take(self.seen, timeout_s)
        self.dropped += dropped
        self.taken += len(records)
        self.last_queue = queue
        self.max_queue = max(self.max_queue, queue)
        return records

    def stats(self) -> dict:
        return {"taken": self.taken, "dropped": self.dropped, "queue": self.last_queue,
                "max_queue": self.max_queue, "streams": len(self.seen)}

