"""ZeroMQ helpers shared by ``serve``, ``replay``, ``tap`` and ``record``.

Socket semantics (the full statement is ``protocol/SPEC.md``):

* **Output** (``live``, ``clean``, ``meta``, and ``raw`` when echoed): the service
  **binds** a PUB socket; subscribers **connect** a SUB socket and subscribe to topic
  prefixes (``sf/live/``, ``sf/clean/kinect0``, ``sf/`` for everything). Every message
  is two frames ``[topic, payload]``. Messages from one publisher arrive in the order
  sent. PUB never blocks: when a subscriber's queue holds SNDHWM messages (default
  1000 here) further messages *to that subscriber only* are dropped, so a stalled
  subscriber cannot stall the service or grow its memory without bound; the
  subscriber sees the loss as a gap in ``seq``. A subscriber that connects late (the
  "slow joiner") misses what was published before its subscription arrived; the
  skeleton message is repeated (default every second) so it can decode what follows.
* **Raw input** to ``serve``: the service **binds** a PULL socket; producers
  (``streamfix replay``, a sensor bridge) **connect** a PUSH socket. A connecting PUSH
  queues messages before the TCP connection completes and blocks at its SNDHWM rather
  than dropping, so no frame is lost to the slow-joiner effect; the producer is
  throttled instead (back-pressure). ``record`` and ``tap`` may also bind a PULL.

:class:`Subscriber` decodes and validates every message: malformed ones are counted
by reason (``counters``) and skipped, never raised, so the messages around them
still come out. :class:`FramePublisher` encodes, stamps ``t_publish_ns`` and repeats
skeleton messages.
"""
from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Union

import zmq

from ..frames import SkeletonFrame
from ..skeletons import Skeleton
from .wire import (
    SkeletonMessage,
    WireError,
    decode_message,
    encode_frame,
    encode_skeleton_message,
    parse_topic,
    topic_for,
    topic_prefix,
)

__all__ = ["Received", "Subscriber", "FramePublisher", "DEFAULT_META_INTERVAL_S"]

log = logging.getLogger("streamfix.transport")

DEFAULT_META_INTERVAL_S = 1.0


@dataclass
class Received:
    """One decoded message: topic bytes, its kind and stream, the decoded message."""

    topic: bytes
    kind: str
    stream: str
    message: Union[SkeletonFrame, SkeletonMessage]
    payload: bytes
    recv_time_ns: int


def _as_bytes(prefix: Union[str, bytes]) -> bytes:
    return prefix.encode() if isinstance(prefix, str) else bytes(prefix)


class Subscriber:
    """Receive, validate and decode streamfix messages.

    ``endpoint`` e.g. ``tcp://127.0.0.1:5556``; SUB connects by default, ``bind=True``
    binds instead; ``socket_type=zmq.PULL`` (with ``bind=True``) receives what PUSH
    producers send. ``prefixes`` are the topic prefixes yielded (also applied in
    software, so they hold for PULL too). With ``learn_skeletons`` the subscriber also
    subscribes to ``sf/meta/`` and keeps every skeleton message it sees in
    ``skeletons`` (name -> Skeleton) and ``stream_info`` (stream -> SkeletonMessage),
    so frames of skeletons outside the registry decode after the first repeat.

    ``curve``: a :class:`~streamfix.transport.curve.CurveClient` for a CURVE service.
    ``counters``: ``received`` (multipart messages), ``frames``, ``skeletons``,
    ``filtered`` (other topics, PULL only),
    ``malformed`` (total skipped as bad), one key per :class:`WireError` reason
    (``garbage``, ``truncated``, ``version``, ``skeleton``, ``joints``, ``field``,
    ``topic``, ``parts``) and ``ignored_type`` (unknown message types, skipped).
    ``on_error(topic, error)`` is called once per skipped message (default: one log line).
    """

    def __init__(
        self,
        endpoint: str,
        prefixes: Iterable[Union[str, bytes]] = (b"sf/",),
        *,
        bind: bool = False,
        socket_type: int = zmq.SUB,
        context: zmq.Context | None = None,
        rcvhwm: int = 100_000,
        learn_skeletons: bool = True,
        on_error: Callable[[bytes, WireError], None] | None = None,
        curve=None,
    ) -> None:
        self.endpoint = endpoint
        self.prefixes = tuple(_as_bytes(p) for p in prefixes) or (b"",)
        self.learn_skeletons = learn_skeletons
        self.counters: Counter = Counter()
        self.skeletons: dict[str, Skeleton] = {}
        self.stream_info: dict[str, SkeletonMessage] = {}
        self.on_error = on_error or self._log_error
        self._own_context = context is None
        self.context = context or zmq.Context()
        self.socket = self.context.socket(socket_type)
        self.socket.setsockopt(zmq.RCVHWM, rcvhwm)
        self.socket.setsockopt(zmq.LINGER, 0)
        if socket_type == zmq.SUB:
            subs = set(self.prefixes)
            if learn_skeletons:
                subs.add(topic_prefix("meta"))
            for p in subs:
                self.socket.setsockopt(zmq.SUBSCRIBE, p)
        if curve is not None:  # a streamfix.transport.curve CurveClient (or CurveServer when binding)
            curve.apply(self.socket)
        if bind:
            self.socket.bind(endpoint)
            self.endpoint = self.socket.getsockopt_string(zmq.LAST_ENDPOINT)
        else:
            self.socket.connect(endpoint)

    @staticmethod
    def _log_error(topic: bytes, error: WireError) -> None:
        log.warning("skipped message on %r: %s", topic, error)

    def _wanted(self, topic: bytes) -> bool:
        return any(topic.startswith(p) for p in self.prefixes)

    def _skip(self, topic: bytes, error: WireError) -> None:
        if error.reason == "type":
            self.counters["ignored_type"] += 1
        else:
            self.counters["malformed"] += 1
            self.counters[error.reason] += 1
        self.on_error(topic, error)

    def decode(self, parts: list[bytes]) -> Received | None:
        """Validate and decode one multipart message; None (and counted) if skipped."""
        now = time.time_ns()
        self.counters["received"] += 1
        if len(parts) != 2:
            topic = parts[0] if parts else b""
            self._skip(topic, WireError(
                f"message has {len(parts)} frames, expected 2 ([topic, payload])", "parts"))
            return None
        topic, payload = parts
        try:
            kind, stream = parse_topic(topic)
        except WireError as exc:
            exc.reason = "topic"
            self._skip(topic, exc)
            return None
        try:
            msg = decode_message(payload, self.skeletons)
        except WireError as exc:
            self._skip(topic, exc)
            return None
        if isinstance(msg, SkeletonMessage):
            if kind != "meta":
                self._skip(topic, WireError(f"skeleton message on {kind!r} topic {topic!r}, expected sf/meta/", "topic"))
                return None
        elif kind == "meta":
            self._skip(topic, WireError(f"frame message on meta topic {topic!r}", "topic"))
            return None
        if msg.stream_id != stream:
            self._skip(topic, WireError(
                f"message for stream {msg.stream_id!r} on topic {topic!r} of stream {stream!r}", "topic"))
            return None
        if isinstance(msg, SkeletonMessage):
            self.counters["skeletons"] += 1
            if self.learn_skeletons:
                self.skeletons[msg.skeleton.name] = msg.skeleton
                self.stream_info[msg.stream_id] = msg
        else:
            self.counters["frames"] += 1
        return Received(bytes(topic), kind, stream, msg, bytes(payload), now)

    def receive(self, count: int | None = None, timeout_s: float | None = None) -> Iterator[Received]:
        """Yield decoded messages on the wanted prefixes.

        Stops after ``count`` yielded messages or ``timeout_s`` seconds in total
        (None: no bound). Malformed messages are counted and skipped.
        """
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        yielded = 0
        poller = zmq.Poller()
        poller.register(self.socket, zmq.POLLIN)
        while count is None or yielded < count:
            if deadline is None:
                wait_ms = 200
            else:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return
                wait_ms = max(1, min(200, int(remaining * 1000)))
            if not poller.poll(wait_ms):
                continue
            parts = self.socket.recv_multipart(copy=True)
            topic = parts[0] if parts else b""
            if self.prefixes != (b"",) and not self._wanted(topic) and not topic.startswith(b"sf/meta/"):
                self.counters["filtered"] += 1  # a PULL socket receives every topic
                continue
            got = self.decode(parts)
            if got is None or not self._wanted(got.topic):
                continue
            yielded += 1
            yield got

    def close(self) -> None:
        self.socket.close(linger=0)
        if self._own_context:
            self.context.term()

    def __enter__(self) -> "Subscriber":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class FramePublisher:
    """Publish frames and skeleton messages as ``[topic, payload]``.

    PUB bound by default (the service's output); ``socket_type=zmq.PUSH, bind=False``
    is a producer feeding ``serve``'s PULL input (blocks at SNDHWM: back-pressure, no
    loss). :meth:`announce` registers a stream's skeleton and rate and sends its
    skeleton message; :meth:`publish` re-sends it first when ``meta_interval_s`` has
    passed, and stamps ``t_publish_ns``.
    """

    def __init__(
        self,
        endpoint: str,
        *,
        bind: bool = True,
        socket_type: int = zmq.PUB,
        context: zmq.Context | None = None,
        sndhwm: int = 1000,
        meta_interval_s: float = DEFAULT_META_INTERVAL_S,
        curve=None,
    ) -> None:
        self._own_context = context is None
        self.context = context or zmq.Context()
        self.socket = self.context.socket(socket_type)
        self.socket.setsockopt(zmq.SNDHWM, sndhwm)
        self.socket.setsockopt(zmq.LINGER, 2000)
        if curve is not None:  # a streamfix.transport.curve CurveServer (bind) or CurveClient (connect)
            curve.apply(self.socket)
        if bind:
            self.socket.bind(endpoint)
            self.endpoint = self.socket.getsockopt_string(zmq.LAST_ENDPOINT)
        else:
            self.socket.connect(endpoint)
            self.endpoint = endpoint
        self.meta_interval_s = meta_interval_s
        self.counters: Counter = Counter()
        self._meta: dict[str, tuple[Skeleton, float]] = {}
        self._meta_sent: dict[str, float] = {}

    def announce(self, stream_id: str, skeleton: Skeleton, rate_hz: float) -> None:
        """Remember a stream's skeleton and rate and send its skeleton message now."""
        self._meta[stream_id] = (skeleton, float(rate_hz))
        self.send_meta(stream_id)

    def send_meta(self, stream_id: str) -> None:
        skeleton, rate = self._meta[stream_id]
        payload = encode_skeleton_message(skeleton, rate, stream_id)
        self.socket.send_multipart([topic_for("meta", stream_id), payload])
        self._meta_sent[stream_id] = time.monotonic()
        self.counters["skeletons"] += 1

    def publish(self, kind: str, frame: SkeletonFrame) -> bytes:
        """Encode and send one frame on ``sf/<kind>/<stream>``; returns the payload."""
        stream = frame.stream_id
        if stream in self._meta and time.monotonic() - self._meta_sent[stream] >= self.meta_interval_s:
            self.send_meta(stream)
        payload = encode_frame(frame, publish_time_ns=time.time_ns())
        self.socket.send_multipart([topic_for(kind, stream), payload])
        self.counters[kind] += 1
        return payload

    def send_raw(self, topic: bytes, payload: bytes) -> None:
        """Send pre-encoded bytes (replaying a recording verbatim, or test garbage)."""
        self.socket.send_multipart([topic, payload])

    def close(self) -> None:
        self.socket.close()
        if self._own_context:
            self.context.term()

    def __enter__(self) -> "FramePublisher":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
