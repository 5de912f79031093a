"""Where ``streamfix serve`` gets raw frames: a bound ZeroMQ endpoint, stdin, or a recording.

``--source`` takes one of:

``tcp://HOST:PORT`` (or any ZeroMQ endpoint, e.g. ``ipc://...``)
    The service **binds a PULL socket** there; senders **connect PUSH sockets**
    (``streamfix replay --to`` does). PUSH/PULL is chosen over PUB/SUB because of
    ZeroMQ's slow-joiner effect: a PUB drops everything sent before the subscription
    has propagated, while a PUSH socket queues messages (up to its SNDHWM) until its
    connection is up and then delivers them in order, and with the service's PULL
    as the only peer there is nothing to load-balance. So no frame is lost whether
    the sender or the service starts first. Each message is either ``[topic,
    payload]`` (as published on ``sf/raw/<stream>``) or just ``[payload]``; the
    payload is a wire ``frame`` message or a ``skeleton`` message (which announces a
    skeleton that is not in the registry, e.g. one read from a BVH file). Several
    senders may connect at once; ZeroMQ fair-queues them.
``stdin``
    Kinect v2 CSV or JSON lines, one frame per line (see
    :mod:`streamfix.service.textin`). The stream ends at end of file.
``replay:FILE``
    Any readable recording (Kinect CSV, BVH, C3D, ``.sfrec`` with all its bodies and
    streams), played at its own timing (``rate`` > 1 plays faster), optionally
    looped; see :mod:`streamfix.service.playback`.

Every source offers ``poll(timeout_s) -> list[Item]`` (returns at most after
``timeout_s``; items are :class:`Frame`, :class:`Announce` or :class:`Rejected`),
``exhausted`` (no more input will come) and ``close()``. Sources never raise on bad
input: a bad message becomes a :class:`Rejected` item carrying the reason, so the
service counts it and carries on.
"""
from __future__ import annotations

import os
import queue
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Union

from ..frames import SkeletonFrame
from ..skeletons import Skeleton
from .playback import Pacer, open_playback
from .textin import parse_line
from .validate import BadInput

__all__ = [
    "Frame",
    "Announce",
    "Rejected",
    "Item",
    "ZmqSource",
    "StdinSource",
    "ReplaySource",
    "open_source",
    "wire_reason",
    "default_replay_file",
]


@dataclass
class Frame:
    """A raw frame, with its arrival time on the monotonic clock (ns)."""

    frame: SkeletonFrame
    arrival_ns: int
    rate_hz: float | None = None


@dataclass
class Announce:
    """A skeleton layout announced on the input (wire skeleton message)."""

    stream_id: str
    skeleton: Skeleton
    rate_hz: float


@dataclass
class Rejected:
    """A message that was skipped: ``reason`` from ``validate.REASONS``, ``detail`` for the log."""

    reason: str
    detail: str


Item = Union[Frame, Announce, Rejected]

# WireError.reason -> service reason (the label of streamfix_malformed_total).
_WIRE_REASONS = {
    "garbage": "garbage",
    "truncated": "truncated",
    "version": "newer_version",
    "skeleton": "unknown_skeleton",
    "joints": "wrong_joint_count",
    "type": "invalid",
    "field": "invalid",
}


def wire_reason(exc: Exception) -> str:
    """Map a ``WireError`` to the service's malformed-input reason."""
    reason = _WIRE_REASONS.get(getattr(exc, "reason", ""), "invalid")
    if reason == "newer_version" and "newer" not in str(exc):
        reason = "invalid"  # version 0 or negative: not newer, just wrong
    return reason


class ZmqSource:
    """PULL socket bound at ``endpoint``; decodes wire messages (see module docstring)."""

    def __init__(self, endpoint: str, *, context=None, rcvhwm: int = 10000, max_batch: int = 256) -> None:
        import zmq

        from ..transport import wire

        self._zmq = zmq
        self._wire = wire
        self._ctx = context or zmq.Context.instance()
        self.sock = self._ctx.socket(zmq.PULL)
        self.sock.setsockopt(zmq.RCVHWM, int(rcvhwm))
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.bind(endpoint)
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._poller = zmq.Poller()
        self._poller.register(self.sock, zmq.POLLIN)
        self._max_batch = int(max_batch)
        self.skeletons: dict[str, Skeleton] = {}
        self.exhausted = False  # a bound socket never ends by itself

    def describe(self) -> str:
        return f"zmq PULL bound at {self.endpoint}"

    def _decode(self, parts: list[bytes]) -> Item:
        wire = self._wire
        if not parts or len(parts) > 2:
            return Rejected("garbage", f"message has {len(parts)} ZeroMQ frames, expected [topic, payload] or [payload]")
        payload = parts[-1]
        try:
            msg = wire.decode_message(payload, self.skeletons)
        except wire.WireError as exc:
            return Rejected(wire_reason(exc), str(exc))
        if isinstance(msg, SkeletonFrame):
            return Frame(msg, time.monotonic_ns())
        # a skeleton message: learn the layout so frames naming it decode
        self.skeletons[msg.skeleton.name] = msg.skeleton
        return Announce(msg.stream_id, msg.skeleton, msg.rate_hz)

    def poll(self, timeout_s: float) -> list[Item]:
        zmq = self._zmq
        items: list[Item] = []
        if not self._poller.poll(max(0, int(timeout_s * 1000))):
            return items
        while len(items) < self._max_batch:
            try:
                parts = self.sock.recv_multipart(zmq.NOBLOCK, copy=True)
            except zmq.Again:
                break
            items.append(self._decode(parts))
        return items

    def close(self) -> None:
        self.sock.close(linger=0)


class StdinSource:
    """Lines from a text stream (stdin by default), read on a daemon thread."""

    def __init__(self, stream=None, *, stream_id: str = "stdin", maxsize: int = 4096) -> None:
        self._stream = stream if stream is not None else sys.stdin
        self.stream_id = stream_id
        self._queue: "queue.Queue[Item | None]" = queue.Queue(maxsize=maxsize)
        self.exhausted = False
        self.skeletons: dict[str, Skeleton] = {}
        self._seq = 0
        self._thread = threading.Thread(target=self._read, name="stdin-source", daemon=True)
        self._thread.start()

    def describe(self) -> str:
        return "stdin (Kinect v2 CSV or JSON lines)"

    def _read(self) -> None:
        try:
            for lineno, line in enumerate(self._stream, 1):
                try:
                    frame = parse_line(line, self.stream_id, self._seq)
                except BadInput as exc:
                    self._queue.put(Rejected(exc.reason, f"stdin line {lineno}: {exc.detail}"))
                    continue
                if frame is None:
                    continue
                if not isinstance(frame, SkeletonFrame):  # a skeleton line announces a layout
                    self.skeletons[frame.skeleton.name] = frame.skeleton
                    self._queue.put(Announce(frame.stream_id, frame.skeleton, frame.rate_hz))
                    continue
                self._seq = frame.seq + 1
                # put() blocks when the service is behind: back-pressure on the pipe, not unbounded memory
                self._queue.put(Frame(frame, time.monotonic_ns()))
        except (OSError, ValueError, UnicodeDecodeError) as exc:
            self._queue.put(Rejected("garbage", f"stdin stopped: {exc}"))
        finally:
            self._queue.put(None)

    def poll(self, timeout_s: float) -> list[Item]:
        items: list[Item] = []
        try:
            first = self._queue.get(timeout=max(timeout_s, 0.0)) if timeout_s > 0 else self._queue.get_nowait()
        except queue.Empty:
            return items
        pending = [first]
        while len(pending) < 256:
            try:
                pending.append(self._queue.get_nowait())
            except queue.Empty:
                break
        for it in pending:
            if it is None:
                self.exhausted = True
            else:
                items.append(it)
        return items

    def close(self) -> None:
        pass  # the daemon reader thread ends with the process


class ReplaySource:
    """A recording played at its own timing (``rate`` x real time), optionally looped."""

    def __init__(self, path: str, *, rate: float = 1.0, loop: bool = False, stream_id: str | None = None) -> None:
        self.path = path
        self.playback = open_playback(path, stream_id=stream_id)
        self.rate = float(rate)
        self.loop = bool(loop)
        self._frames = self.playback.frames(loop)
        self._pacer = Pacer(rate)
        self._next = next(self._frames, None)
        self.exhausted = self._next is None
        self._announced = False
        self.skeletons = {skel.name: skel for _, skel, _ in self.playback.announce}

    def describe(self) -> str:
        loop = ", looped" if self.loop else ""
        return f"replay of {self.playback.describe()}, rate x{self.rate:g}{loop}"

    def poll(self, timeout_s: float) -> list[Item]:
        items: list[Item] = []
        if not self._announced:
            self._announced = True
            items.extend(Announce(sid, skel, rate) for sid, skel, rate in self.playback.announce)
        if self._next is None:
            self.exhausted = True
            if timeout_s > 0 and not items:
                time.sleep(min(timeout_s, 0.01))
            return items
        wait = self._pacer.wait_time(self._next[0])
        if wait > 0:
            if items:
                return items
            time.sleep(min(wait, timeout_s))
        while self._next is not None and self._pacer.wait_time(self._next[0]) <= 0 and len(items) < 256:
            items.append(Frame(self._next[1], time.monotonic_ns(), self.playback.rate_hz))
            self._next = next(self._frames, None)
        if self._next is None:
            self.exhausted = True
        return items

    def close(self) -> None:
        self._frames.close()


def default_replay_file(project_root: Path | None = None) -> Path:
    """The bundled demo recording: the first ``.csv`` in ``replay_data/`` (sorted by name).

    Looks in ``$STREAMFIX_REPLAY_DATA`` if set, else in ``replay_data/`` of the project
    checkout next to the package and of the current directory; raises
    FileNotFoundError saying where it looked.
    """
    env = os.environ.get("STREAMFIX_REPLAY_DATA")
    if env:  # an explicit directory wins outright
        candidates = [Path(env)]
    else:
        roots = [Path(project_root)] if project_root is not None else []
        roots.extend([Path(__file__).resolve().parents[2], Path.cwd()])
        candidates = [r / "replay_data" for r in roots]
    for d in candidates:
        if d.is_dir():
            csvs = sorted(p for p in d.iterdir() if p.suffix.lower() == ".csv" and p.is_file())
            if csvs:
                return csvs[0]
    where = ", ".join(str(c) for c in candidates)
    raise FileNotFoundError(
        f"no --source given and no demo recording found (looked for a .csv in: {where}); "
        "pass --source replay:FILE, --source stdin or --source tcp://127.0.0.1:PORT"
    )


def open_source(spec: str, *, rate: float = 1.0, loop: bool = False, stream_id: str | None = None, context=None):
    """Open the source named by ``--source`` (see module docstring)."""
    if spec == "stdin" or spec == "-":
        return StdinSource(stream_id=stream_id or "stdin")
    if spec.startswith("replay:"):
        path = spec[len("replay:"):]
        if not Path(path).is_file():
            raise FileNotFoundError(f"--source replay:{path}: no such file")
        return ReplaySource(path, rate=rate, loop=loop, stream_id=stream_id)
    if "://" in spec:
        return ZmqSource(spec, context=context)
    raise ValueError(
        f"--source {spec!r} is not understood; expected tcp://HOST:PORT (bound PULL), stdin, or replay:FILE"
    )
