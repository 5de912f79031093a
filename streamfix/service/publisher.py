"""The service's output: one ZeroMQ PUB socket, wire messages on ``sf/<kind>/<stream>`` topics.

Kinds (``streamfix.transport.wire.KINDS``): ``raw`` (the validated input, passed
through), ``live`` (low-latency output), ``clean`` (refined output) and ``meta`` (the
skeleton message, sent when a stream first appears and then every
``meta_interval_s`` seconds so that a late subscriber can decode frames).

Slow subscribers: the socket has a send high-water mark (``SNDHWM`` messages per
subscriber) and every send is ``NOBLOCK``. A PUB socket never blocks: once a
subscriber's queue holds SNDHWM messages, libzmq drops further messages *for that
subscriber only*; other subscribers keep receiving everything. So a stalled
subscriber can neither stall the service nor grow its memory beyond about
``SNDHWM`` messages plus the kernel's socket buffers. libzmq does not tell the sender
about those per-subscriber drops (subscribers see them as gaps in ``seq``); what the
service can see - a send refused with EAGAIN or another ZeroMQ error - is counted per
topic kind in :attr:`ServicePublisher.drops` (``streamfix_publish_drops_total{topic=...}``).

On close the socket lingers ``linger_ms`` so queued messages still go out.
"""
from __future__ import annotations

import time
from collections import Counter

import zmq

from ..frames import SkeletonFrame
from ..transport.wire import encode_frame, encode_skeleton_message, topic_for
from ..transport.zmq_io import DEFAULT_META_INTERVAL_S, FramePublisher

__all__ = ["ServicePublisher"]


class ServicePublisher(FramePublisher):
    """The service's PUB socket: like :class:`FramePublisher`, but never blocks or raises.

    Every send is ``NOBLOCK``; a refused send is counted in ``drops[kind]`` and the
    service goes on. ``counters[kind]`` counts messages handed to ZeroMQ per kind.
    """

    def __init__(
        self,
        endpoint: str = "tcp://127.0.0.1:5556",
        *,
        sndhwm: int = 1000,
        linger_ms: int = 2000,
        meta_interval_s: float = DEFAULT_META_INTERVAL_S,
        context: zmq.Context | None = None,
        curve=None,
    ) -> None:
        super().__init__(
            endpoint, bind=True, socket_type=zmq.PUB, context=context,
            sndhwm=sndhwm, meta_interval_s=meta_interval_s, curve=curve,
        )
        self.socket.setsockopt(zmq.LINGER, int(linger_ms))
        self.drops: Counter = Counter()

    def _send(self, kind: str, topic: bytes, payload: bytes) -> bool:
        try:
            self.socket.send_multipart([topic, payload], zmq.NOBLOCK, copy=False)
        except zmq.ZMQError:  # EAGAIN (queue full) or a socket error: count, never stall
            self.drops[kind] += 1
            return False
        self.counters[kind] += 1
        return True

    def send_meta(self, stream_id: str) -> None:
        skeleton, rate = self._meta[stream_id]
        payload = encode_skeleton_message(skeleton, rate, stream_id)
        self._send("meta", topic_for("meta", stream_id), payload)
        self._meta_sent[stream_id] = time.monotonic()

    def announce(self, stream_id: str, skeleton, rate_hz: float) -> None:
        """Register a stream's skeleton; its meta message goes out now if new or changed."""
        if self._meta.get(stream_id) == (skeleton, float(rate_hz)):
            return
        super().announce(stream_id, skeleton, rate_hz)

    def forget(self, stream_id: str) -> None:
        """Stop repeating a stream's skeleton message (the stream ended)."""
        self._meta.pop(stream_id, None)
        self._meta_sent.pop(stream_id, None)

    def publish(self, kind: str, frame: SkeletonFrame) -> bool:  # type: ignore[override]
        """Encode and send one frame on ``sf/<kind>/<stream>``; stamps ``publish_time_ns``."""
        now = time.time_ns()
        frame.publish_time_ns = now
        return self._send(kind, topic_for(kind, frame.stream_id), encode_frame(frame, publish_time_ns=now))

    def tick(self, now: float | None = None) -> None:
        """Repeat each stream's meta message once ``meta_interval_s`` has passed (also when idle)."""
        now = time.monotonic() if now is None else now
        for stream_id, sent in list(self._meta_sent.items()):
            if now - sent >= self.meta_interval_s:
                self.send_meta(stream_id)
