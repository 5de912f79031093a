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
    skeleton that is not in the registry, e.g. one read from a BVH file, for the
    announcing stream only). Several senders may connect at once; ZeroMQ fair-queues
    them. A receiver thread stamps each message's arrival and keeps it in a bounded
    :class:`Backlog` (overload policy ``shed`` or ``block``); with CURVE
    (:mod:`streamfix.transport.curve`) only producers holding an allowed key connect.
``stdin``
    Kinect v2 CSV or JSON lines, one frame per line (see
    :mod:`streamfix.service.textin`). The stream ends at end of file.
``replay:FILE`` or just ``FILE``
    Any readable recording (Kinect CSV, BVH, C3D, ``.sfrec`` with all its bodies and
    streams), played at its own timing (``speed`` > 1 plays faster), optionally
    looped; see :mod:`streamfix.service.playback`. A bare path is a replay when it
    names an existing file.
``depthai[:model=ID,fps=HZ,device=ID]``
    Spatial body keypoints (COCO-17 or BlazePose-33) from a Luxonis OAK camera
    through the DepthAI v3 API (:mod:`streamfix.io.depthai_device`), converted to
    metres in the protocol's camera axes (:mod:`streamfix.io.depthai_keypoints`).
    :class:`DepthaiSource` also reads any host queue of ``SpatialImgDetections``.
``azure-kinect``
    Live Azure Kinect capture (a Python binding of Microsoft's Sensor and Body Tracking
    SDKs) is not built in yet, so this says how to get the same data through a file:
    record with ``k4arecorder``, export with the Body Tracking SDK's ``offline_processor``
    and serve the JSON (``--source take.json``, :mod:`streamfix.io.azure_kinect`).

Every source offers ``poll(timeout_s) -> list[Item]`` (returns at most after
``timeout_s``; items are :class:`Frame`, :class:`Announce`, :class:`Rejected`,
:class:`Limited` or :class:`Shed`), ``exhausted`` (no more input will come) and
``close()``; the ZeroMQ source also ``pending()`` (backlog depth and age) and
``drop_pending()`` (shutdown: count what is left). Sources never raise on bad
input: a bad message becomes a :class:`Rejected` item carrying the reason, so the
service counts it and carries on.
"""
from __future__ import annotations

import os
import queue
import sys
import threading
import time
from collections import Counter
from pathlib import Path

from ..frames import SkeletonFrame
from .backlog import Backlog
from .items import Announce, Frame, Item, Limited, Rejected, Shed, wire_reason
from .limits import Limits
from .playback import Pacer, open_playback
from .scope import SkeletonScope
from .textin import parse_line
from .validate import BadInput, LimitHit

__all__ = [
    "ZmqSource",
    "StdinSource",
    "ReplaySource",
    "DepthaiSource",
    "open_source",
    "check_source",
    "default_replay_file",
]


class ZmqSource:
    """PULL socket bound at ``endpoint``; decodes wire messages (see module docstring).

    A daemon thread receives (so arrival times are true under load) into a
    :class:`Backlog`; :meth:`poll` decodes on the caller's thread. The thread starts at the
    first :meth:`poll` (or :meth:`start`): until the service takes input, messages wait in
    the socket's queue (and the producers' ones: PUSH blocks, nothing is lost) instead of
    ageing in the backlog, which would shed them as too old. Messages over
    ``limits.max_message_bytes`` are skipped before decoding (counted); ZeroMQ's
    ``MAXMSGSIZE`` (16 x that) disconnects a peer sending anything larger, so no single
    message can make the service allocate more. ``curve``: a
    :class:`~streamfix.transport.curve.CurveServer` to authenticate producers.
    """

    def __init__(
        self,
        endpoint: str,
        *,
        context=None,
        rcvhwm: int = 10000,
        max_batch: int = 32,
        limits: Limits | None = None,
        backlog: Backlog | None = None,
        scope: SkeletonScope | None = None,
        curve=None,
    ) -> None:
        import zmq

        from ..transport import wire

        self._zmq = zmq
        self._wire = wire
        self.limits = limits or Limits()
        self.scope = scope if scope is not None else SkeletonScope(self.limits)
        self.backlog = backlog or Backlog()
        self._ctx = context or zmq.Context.instance()
        self.sock = self._ctx.socket(zmq.PULL)
        self.sock.setsockopt(zmq.RCVHWM, int(rcvhwm))
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.MAXMSGSIZE, 16 * int(self.limits.max_message_bytes))
        if curve is not None:
            curve.apply(self.sock)
        self.sock.bind(endpoint)
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._max_batch = int(max_batch)
        self.exhausted = False  # a bound socket never ends by itself
        # producers cut off: gone away, or over MAXMSGSIZE (libzmq drops the message and the connection)
        self.disconnects = 0
        self._monitor = self.sock.get_monitor_socket(zmq.EVENT_DISCONNECTED)
        self._running = True
        self._thread = threading.Thread(target=self._receive, name="zmq-source", daemon=True)

    def describe(self) -> str:
        return f"zmq PULL bound at {self.endpoint}"

    def start(self) -> None:
        """Start receiving (idempotent; :meth:`poll` calls it)."""
        if self._running and self._thread.ident is None:
            self._thread.start()

    def _receive(self) -> None:
        zmq = self._zmq
        poller = zmq.Poller()
        poller.register(self.sock, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        while self._running:
            try:
                ready = dict(poller.poll(50))
                if self._monitor in ready:
                    while self._monitor.poll(0):
                        self._monitor.recv_multipart()
                        self.disconnects += 1
                if self.sock not in ready:
                    continue
                for _ in range(1024):
                    parts = self.sock.recv_multipart(zmq.NOBLOCK, copy=True)
                    self.backlog.put(parts, time.monotonic_ns())
            except zmq.Again:
                continue
            except zmq.ZMQError:  # socket closed under us: the service is stopping
                return

    def _decode(self, parts: list[bytes], arrival_ns: int, newest: bool = True) -> Item:
        wire = self._wire
        if not parts or len(parts) > 2:
            return Rejected("garbage", f"message has {len(parts)} ZeroMQ frames, expected [topic, payload] or [payload]")
        payload = parts[-1]
        if len(payload) > self.limits.max_message_bytes:
            return Limited("message_size", f"message of {len(payload)} bytes, at most "
                                           f"{self.limits.max_message_bytes} (serve --max-message-bytes)")
        try:
            msg = wire.decode_message(payload, self.scope.table)
        except wire.WireError as exc:
            return Rejected(wire_reason(exc), str(exc))
        if isinstance(msg, SkeletonFrame):
            return Frame(msg, arrival_ns, newest=newest)
        # a skeleton message: learn the layout (for this stream only) so its frames decode
        try:
            self.scope.announce(msg.stream_id, msg.skeleton, msg.rate_hz)
        except LimitHit as exc:
            return Limited(exc.limit, exc.detail)
        return Announce(msg.stream_id, msg.skeleton, msg.rate_hz, registered=True)

    def poll(self, timeout_s: float) -> list[Item]:
        self.start()
        got, shed = self.backlog.take(max(0.0, timeout_s), self._max_batch)
        items: list[Item] = [Shed(stream, n) for stream, n in shed.items()]
        items.extend(self._decode(parts, arrival, newest) for parts, arrival, _, _, newest in got)
        return items

    def pending(self) -> tuple[int, float]:
        """Input waiting to be handled: (messages, age of the oldest in seconds)."""
        self.start()
        return self.backlog.depth()

    def wake(self) -> None:
        """Make a :meth:`poll` waiting for input return now (thread-safe)."""
        self.backlog.wake()

    def drop_pending(self) -> list[Item]:
        """Give up on what still waits (shutdown): stop receiving, then count what the backlog
        and the socket's queue still hold, one :class:`Shed` per stream."""
        self._running = False
        self.backlog.close()
        if self._thread.ident is not None:
            self._thread.join(timeout=1.0)
        counts = Counter(self.backlog.drop_all())
        zmq = self._zmq
        try:
            while True:
                parts = self.sock.recv_multipart(zmq.NOBLOCK)
                stream, meta = Backlog._stream_of(parts)
                if not meta:
                    counts[stream] += 1
        except zmq.ZMQError:  # Again: the queue is empty
            pass
        return [Shed(stream, n, "shutdown") for stream, n in counts.items()]

    def close(self) -> None:
        self._running = False
        self.backlog.close()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        self.sock.disable_monitor()
        self._monitor.close(linger=0)
        self.sock.close(linger=0)


class StdinSource:
    """Lines from a text stream (stdin by default), read on a daemon thread.

    The thread starts at the first :meth:`poll` (or :meth:`start`): a line waits in the pipe
    until the service takes input, so its arrival time is not stamped while the service starts.
    """

    def __init__(self, stream=None, *, stream_id: str = "stdin", maxsize: int = 4096) -> None:
        self._stream = stream if stream is not None else sys.stdin
        self.stream_id = stream_id
        self._queue: "queue.Queue[Item | None]" = queue.Queue(maxsize=maxsize)
        self.exhausted = False
        self._seq = 0
        self._thread = threading.Thread(target=self._read, name="stdin-source", daemon=True)

    def start(self) -> None:
        """Start reading (idempotent; :meth:`poll` calls it)."""
        if self._thread.ident is None:
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
                except Exception as exc:  # one line the parser did not foresee must not end the input
                    self._queue.put(Rejected("invalid", f"stdin line {lineno}: {type(exc).__name__}: {exc}"))
                    continue
                if frame is None:
                    continue
                if not isinstance(frame, SkeletonFrame):
                    # a skeleton line announces a layout: the service checks it (a built-in name
                    # cannot be redefined) and keeps it for that stream; this thread runs ahead of
                    # the service, so it must not keep the layout itself
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
        self.start()
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
        return f"replay of {self.playback.describe()}, speed x{self.rate:g}{loop}"

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


class DepthaiSource:
    """``SpatialImgDetections`` from a DepthAI host queue, as frames of one stream.

    ``queue`` is a ``dai.MessageQueue`` (``output.createOutputQueue()``) of a started
    ``pipeline``; each message becomes one frame (:func:`~streamfix.io.depthai_keypoints.detections_to_frame`)
    stamped with the message's timestamp and sequence number, at the nominal ``rate_hz``.
    The stream ends when the queue is closed (the pipeline stopped). A message that
    cannot be converted (an unsupported keypoint count) is :class:`Rejected`.
    """

    def __init__(self, pipeline, queue, *, stream_id: str = "depthai", rate_hz: float = 30.0) -> None:
        from datetime import timedelta

        from ..io.depthai_keypoints import KEYPOINT_LAYOUTS

        self._timedelta = timedelta
        self.pipeline = pipeline
        self.queue = queue
        self.stream_id = stream_id
        self.rate_hz = float(rate_hz)
        self.exhausted = False
        self.skeletons = {s.name: s for s in KEYPOINT_LAYOUTS.values()}
        self._layout = next(iter(KEYPOINT_LAYOUTS.values()))
        # what the queue raises once closed (dai.MessageQueue.QueueException)
        self._closed_error = getattr(type(queue), "QueueException", RuntimeError)

    def describe(self) -> str:
        return f"DepthAI spatial keypoints at {self.rate_hz:g} Hz as stream {self.stream_id!r}"

    def _messages(self, timeout_s: float) -> list:
        try:
            first = self.queue.get(self._timedelta(seconds=timeout_s)) if timeout_s > 0 else self.queue.tryGet()
            if first is None:
                return []
            return [first, *self.queue.tryGetAll()]
        except self._closed_error:  # closed: the pipeline stopped
            self.exhausted = True
            return []

    def poll(self, timeout_s: float) -> list[Item]:
        from ..io.depthai_keypoints import KeypointLayoutError, detections_to_frame

        items: list[Item] = []
        for message in self._messages(max(0.0, timeout_s)):
            try:
                frame = detections_to_frame(message, self.stream_id, empty_layout=self._layout)
            except KeypointLayoutError as exc:
                items.append(Rejected("wrong_joint_count", f"DepthAI message: {exc}"))
                continue
            except (ValueError, AttributeError, TypeError) as exc:  # not SpatialImgDetections, or a bad unit
                items.append(Rejected("invalid", f"DepthAI message: {exc}"))
                continue
            self._layout = self.skeletons[frame.skeleton]
            items.append(Frame(frame, time.monotonic_ns(), self.rate_hz))
        return items

    def close(self) -> None:
        """Stop the pipeline and wait for its threads. The wait releases the GIL; the
        pipeline's destructor joins the same threads while holding it, so a host node thread
        still returning into Python when the last reference went hung the process (seen
        once in the test suite, a deadlock between ``~PipelineImpl`` and ``take_gil``)."""
        if self.pipeline is None:
            return
        try:
            if self.pipeline.isRunning():
                self.pipeline.stop()
            self.pipeline.wait()
        except RuntimeError:
            pass


def open_depthai_source(spec: str, stream_id: str | None = None) -> DepthaiSource:
    """``--source depthai[:...]`` on a device; RuntimeError when depthai or a device is missing."""
    from ..io.depthai_device import open_device_pipeline, parse_depthai_spec

    options = parse_depthai_spec(spec)
    pipeline, queue = open_device_pipeline(options)
    return DepthaiSource(pipeline, queue, stream_id=stream_id or "depthai", rate_hz=options.fps)


def open_azure_kinect_source(spec: str):
    """``--source azure-kinect``: always a RuntimeError saying live capture is not built in and what works today."""
    via_file = ("record with k4arecorder, export the bodies with the Body Tracking SDK's offline_processor "
                "and serve the JSON file: --source take.json")
    # one message whether the optional binding is installed or not: installing it does not
    # make live capture work (the capture loop is not built in), so it is not suggested
    raise RuntimeError(f"--source {spec}: live Azure Kinect capture is not built in yet; {via_file}")


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


def _source_kind(spec: str) -> str:
    """``stdin``, ``depthai``, ``azure-kinect``, ``replay`` or ``zmq`` for ``--source spec``;
    FileNotFoundError / ValueError when it names no file or nothing understood."""
    if spec == "stdin" or spec == "-":
        return "stdin"
    if spec == "depthai" or spec.startswith("depthai:"):
        return "depthai"
    if spec == "azure-kinect":
        return "azure-kinect"
    if spec.startswith("replay:"):
        if not Path(spec[len("replay:"):]).is_file():
            raise FileNotFoundError(f"--source {spec}: no such file")
        return "replay"
    if "://" in spec:
        return "zmq"
    if Path(spec).is_file():
        return "replay"
    raise ValueError(
        f"--source {spec!r} is not understood (and is no file); expected tcp://HOST:PORT (bound PULL), stdin, "
        "depthai[:model=ID,fps=HZ], azure-kinect, replay:FILE or the path of a recording"
    )


def check_source(spec: str) -> None:
    """Raise now what :func:`open_source` would raise for a source that is known not to open
    without opening it (an unknown spec, no such file, no DepthAI package, camera or model):
    ``serve`` calls this before it spends seconds building the engine, so a camera that is
    not attached or a mistyped file is said at once. A ZeroMQ endpoint is checked when it is
    bound, a recording when it is read."""
    kind = _source_kind(spec)
    if kind == "depthai":
        from ..io.depthai_device import check_device, parse_depthai_spec

        check_device(parse_depthai_spec(spec))
    elif kind == "azure-kinect":
        open_azure_kinect_source(spec)


def open_source(spec: str, *, speed: float = 1.0, loop: bool = False, stream_id: str | None = None, context=None,
                **zmq_options):
    """Open the source named by ``--source`` (see module docstring); ``speed`` paces a
    replay (x real time); ``zmq_options`` go to :class:`ZmqSource` (limits, backlog, curve)."""
    kind = _source_kind(spec)
    if kind == "stdin":
        return StdinSource(stream_id=stream_id or "stdin")
    if kind == "depthai":
        return open_depthai_source(spec, stream_id)
    if kind == "azure-kinect":
        return open_azure_kinect_source(spec)
    if kind == "zmq":
        return ZmqSource(spec, context=context, **zmq_options)
    path = spec[len("replay:"):] if spec.startswith("replay:") else spec
    return ReplaySource(path, rate=speed, loop=loop, stream_id=stream_id)
