"""The viewer's ZeroMQ side: a service's ``raw``, ``live`` and ``clean`` topics onto a board.

Semantics (see ``protocol/SPEC.md``): the bridge **connects** a SUB socket to the
service's PUB endpoint and subscribes to ``sf/raw/``, ``sf/live/``, ``sf/clean/`` and
``sf/meta/`` (every stream). It is a late joiner like any subscriber: what was
published before it connected is not seen, and a stream's layout is known from its
skeleton message (repeated every second) or the built-in registry. Decoding and
validation are :class:`streamfix.transport.zmq_io.Subscriber`'s; malformed messages are
counted there and skipped.

The bridge drains its socket continuously on its own thread and does nothing slow per
message (the board keeps the newest few records), so the service's PUB never queues for
it; its receive high-water mark is small, so if the process stalls, ZeroMQ drops for
this subscriber alone rather than buffering minutes of frames.
"""
from __future__ import annotations

import threading

from ..frames import SkeletonFrame
from ..skeletons import get_skeleton
from .board import FrameBoard

__all__ = ["ZmqBridge"]

_TOPICS = (b"sf/raw/", b"sf/live/", b"sf/clean/")


class ZmqBridge:
    """Feed a :class:`FrameBoard` from a service's PUB endpoint on a daemon thread."""

    def __init__(self, endpoint: str, board: FrameBoard, *, rcvhwm: int = 1000) -> None:
        from ..transport.zmq_io import Subscriber

        self.endpoint = endpoint
        self.board = board
        self.subscriber = Subscriber(endpoint, _TOPICS, rcvhwm=rcvhwm)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="streamfix-view-bridge", daemon=True)

    @property
    def counters(self):
        return self.subscriber.counters

    def start(self) -> "ZmqBridge":
        self._thread.start()
        return self

    def _run(self) -> None:
        sub = self.subscriber
        known: dict[str, object] = {}
        while not self._stop.is_set():
            for got in sub.receive(timeout_s=0.2):
                msg = got.message
                if not isinstance(msg, SkeletonFrame):
                    continue
                info = sub.stream_info.get(got.stream)
                key = info.skeleton if info is not None else msg.skeleton
                if known.get(got.stream) != key:  # new stream, or its skeleton message changed
                    skeleton = info.skeleton if info is not None else (
                        sub.skeletons.get(msg.skeleton) or get_skeleton(msg.skeleton))
                    self.board.set_layout(got.stream, skeleton, info.rate_hz if info is not None else None)
                    known[got.stream] = key
                self.board.ingest(got.kind, msg, got.recv_time_ns)
                if self._stop.is_set():
                    break

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        self.subscriber.close()
