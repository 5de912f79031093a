"""``streamfix serve`` orchestration: source -> validate -> engine per stream -> publisher.

One thread runs the loop (the metrics HTTP server and a stdin reader, if used, have
their own daemon threads; the engine may solve windows on its own worker):

1. ``source.poll(<=10 ms)`` gives raw frames, skeleton announcements and rejected
   messages. A rejected or invalid message is counted under its reason
   (``streamfix_malformed_total{reason}``), logged in one line, and skipped.
2. A valid frame is pushed into its stream's engine (created on the stream's first
   frame, from its skeleton and rate), passed through on ``raw``, and whatever the
   engine returns goes out on ``live`` / ``clean``. A stream whose skeleton changes,
   or whose ``seq`` jumps back by more than a second's worth (the sender restarted),
   has its engine flushed and replaced; a stream that sends nothing for
   ``idle_timeout_s`` is flushed (its last lookahead's frames come out) and forgotten. Outputs the engine finishes in the
   background are collected with ``engine.poll()`` on every turn, after the input already
   waiting (for at most a turn: a poll also hands the windows those frames scheduled to the
   solver, which would otherwise compete with their live output); an engine that finishes a
   window wakes a source that can be woken (``source.wake()``: the ZeroMQ input), so its clean
   frames leave at once instead of after the rest of a 10 ms wait for input. Input that
   arrives while engines are polled is handled before the next engine's poll.
   After each frame and before each engine's poll the loop yields the CPU
   (``os.sched_yield``): on a busy core the scheduler lets a running thread finish its
   time slice before a woken one of the same priority runs, so without it the ZeroMQ
   threads that receive the next stream's frame and send the live frame just published
   waited for the loop to block (``benchmarks/bench_service.py`` measures the effect:
   many streams arriving together on one core).
3. The skeleton message of every stream is repeated each ``meta_interval_s``; a
   one-line status goes to stderr every ``status_interval_s`` (0: never) and once at exit
   (when the interval is positive, or ``status_at_exit``: ``serve --status-interval 0``).

Containment: nothing a producer sends can raise out of the loop. Messages over a
resource limit (:mod:`.limits`) are counted under ``streamfix_limit_hits_total{limit}``
and skipped (or, for bodies and coordinates, the offending part is dropped). An
exception from a stream's engine or its output (a bug, ``MemoryError``) is counted
under ``streamfix_stream_failures_total{stage}``, the stream's engine is discarded,
and its next frame starts it afresh in a new epoch; other streams are untouched.
Engine restarts of any cause are counted in ``streamfix_stream_restarts_total{cause}``.

Sequence numbers: the service renumbers each stream's output per
:mod:`.numbering` (``epoch`` and ``seq`` on the wire; ``seq`` can never overflow).

Overload: the source keeps what it received in a bounded backlog
(:class:`~.backlog.Backlog`) and sheds the oldest frames beyond it; a frame too old is shed
only when a later one of its stream is at hand (so a burst that ends while the loop is busy
still shows its last pose; see the backlog for its bound); shed frames are
counted (``streamfix_shed_frames_total{reason}``) and announced on the wire as
``dropped`` on the stream's next ``live`` frame. ``streamfix_input_backlog_frames`` /
``_seconds`` show the backlog.

Shutdown: SIGINT/SIGTERM (or the end of a ``replay:``/``stdin`` source) stops the
loop; what the source has already received is handled for at most
``drain_timeout_s`` and the rest is counted as shed (``reason="shutdown"``) and logged;
every engine is flushed (``engine.flush()`` emits each pending frame, waiting at most
``flush_timeout_s`` for windows), those frames are published, and only then are the
sockets closed, with LINGER so queued messages still leave.

Latencies (seconds, monotonic clock, from a frame's arrival at the service's socket):
``streamfix_live_latency_seconds`` / ``streamfix_clean_latency_seconds`` end to end
up to the publish call; ``streamfix_live_compute_seconds`` the engine call that
produced the live frame; ``streamfix_clean_compute_seconds`` how long after the
input frame that completed its window (the lookahead) a clean frame came out -
i.e. the clean latency beyond the lookahead.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import signal
import sys
import threading
import time
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Callable

from ..frames import SkeletonFrame
from ..skeletons import Skeleton, get_skeleton
from ..transport.wire import WireError, check_stream_id
from .items import Announce, Frame, Limited, Rejected, Shed
from .limits import LIMITS, Limits
from .metrics import MetricsServer, Registry
from .numbering import Numbering
from .publisher import ServicePublisher
from .scope import SkeletonScope
from .validate import REASONS, BadInput, LimitHit, check_rate, limit_coordinates, short, validate_frame

__all__ = ["Service", "ServiceMetrics"]

log = logging.getLogger("streamfix.service")

_MAX_PENDING = 100_000  # arrival times kept per stream for latency accounting
_MAX_NUMBERINGS = 1024  # streams whose seq/epoch state outlives their engine (LRU)
_MAX_STREAM_LABELS = 64  # label sets of ended streams kept in per-stream metrics
#: ``streamfix_stream_failures_total{stage}``: where a contained exception came from
FAILURE_STAGES = ("engine", "output", "flush")
#: ``streamfix_stream_restarts_total{cause}``: why a stream's engine was started afresh
RESTART_CAUSES = ("producer_restart", "clock_reset", "skeleton_change", "failure")
# a stream's sensor time this far behind its newest frame is a reset sensor clock (a restarted
# sensor or bridge), not a frame out of order: its engine starts afresh instead of skipping
# every later frame as late
_CLOCK_RESET_NS = 1_000_000_000
# engine counters forwarded as streamfix_engine_events_total{event=...}
_ENGINE_EVENTS = ("windows_solved", "windows_skipped", "windows_abandoned", "solver_errors", "degrade_events")


_yield_cpu: Callable[[], None] = getattr(os, "sched_yield", None) or (lambda: None)
"""Let other runnable threads of this CPU run now (module doc, step 2); a no-op where the
platform has no ``sched_yield``."""


class ServiceMetrics:
    """The service's metric families (see ``docs``: names are part of the interface)."""

    def __init__(self) -> None:
        r = self.registry = Registry()
        self.frames_in = r.counter("streamfix_frames_in_total", "Valid raw frames received, per stream.", ("stream",))
        self.frames_out = r.counter(
            "streamfix_frames_out_total", "Messages published, per topic kind (raw, live, clean, meta).", ("topic",)
        )
        self.malformed = r.counter(
            "streamfix_malformed_total", "Input messages skipped as malformed, per reason.", ("reason",)
        )
        self.drops = r.counter(
            "streamfix_publish_drops_total", "Output messages the PUB socket refused (not sent), per topic kind.", ("topic",)
        )
        self.nonfinite = r.counter(
            "streamfix_nonfinite_joints_total", "Input joints with NaN/inf coordinates (treated as missing)."
        )
        self.late = r.counter(
            "streamfix_frames_late_total", "Input frames skipped by the engine as duplicate or out of order."
        )
        self.filled = r.counter(
            "streamfix_filled_frames_total", "Frames synthesised for sensor frames that never arrived."
        )
        self.streams = r.gauge("streamfix_streams", "Streams with a running engine.")
        self.bodies = r.gauge("streamfix_bodies", "Bodies in the latest frame, summed over streams.")
        self.degraded = r.gauge("streamfix_degraded", "1 while any engine runs degraded (solver behind), else 0.")
        self.degrade_level = r.gauge(
            "streamfix_degrade_level", "Deepest degradation level of any engine (0 none; 1 fewer iterations; 2-3 larger hop)."
        )
        self.engine_events = r.counter(
            "streamfix_engine_events_total", "Engine window events (solved, skipped, abandoned, solver errors).", ("event",)
        )
        self.live_compute = r.histogram("streamfix_live_compute_seconds", "Engine time to produce a live frame.")
        self.clean_compute = r.histogram(
            "streamfix_clean_compute_seconds", "Clean output delay beyond the lookahead (window solve + queueing)."
        )
        self.live_latency = r.histogram("streamfix_live_latency_seconds", "Arrival to publish of a live frame.")
        self.clean_latency = r.histogram(
            "streamfix_clean_latency_seconds", "Arrival to publish of a clean frame (lookahead + compute)."
        )
        self.limit_hits = r.counter(
            "streamfix_limit_hits_total", "Messages, bodies or joints over a resource limit (skipped), per limit.", ("limit",)
        )
        self.failures = r.counter(
            "streamfix_stream_failures_total",
            "Exceptions contained to one stream (its engine is restarted), per stage.", ("stage",)
        )
        self.restarts = r.counter(
            "streamfix_stream_restarts_total", "Stream engines started afresh (a new epoch), per cause.", ("cause",)
        )
        self.shed = r.counter(
            "streamfix_shed_frames_total", "Input frames dropped unprocessed (overload backlog, shutdown), per reason.",
            ("reason",)
        )
        self.disconnects = r.counter(
            "streamfix_input_disconnects_total",
            "Producer connections closed: the peer went away, or sent a message over 16 x the message size "
            "limit (ZeroMQ drops it and cuts the connection).",
        )
        self.backlog = r.gauge("streamfix_input_backlog_frames", "Input messages received and waiting to be handled.")
        self.backlog_age = r.gauge(
            "streamfix_input_backlog_seconds", "How long the oldest waiting input message has waited."
        )
        for limit in LIMITS:
            self.limit_hits.touch(limit=limit)
        for stage in FAILURE_STAGES:
            self.failures.touch(stage=stage)
        for cause in RESTART_CAUSES:
            self.restarts.touch(cause=cause)
        for reason in ("backlog", "shutdown"):
            self.shed.touch(reason=reason)
        for reason in REASONS:
            self.malformed.touch(reason=reason)
        for event in _ENGINE_EVENTS:
            self.engine_events.touch(event=event)
        for kind in ("raw", "live", "clean", "meta"):
            self.frames_out.touch(topic=kind)
            self.drops.touch(topic=kind)


@dataclass
class _Stream:
    stream_id: str
    skeleton: Skeleton
    rate_hz: float
    engine: object
    lookahead: int = 0  # frames the clean output waits for
    # real input frames by sensor time (the engine keeps sensor times; seq may be renumbered)
    arrivals: "OrderedDict[int, tuple[int, int]]" = field(default_factory=OrderedDict)  # t -> (arrival, index)
    by_index: deque = field(default_factory=deque)  # arrival ns of input frame base_index + k
    base_index: int = 0
    last_arrival_ns: int = 0
    bodies: int = 0
    frames: int = 0
    late_seen: int = 0
    events_seen: dict = field(default_factory=dict)
    last_seq: int | None = None
    last_active_ns: int = 0  # when the service last handled a frame of this stream
    numbering: Numbering = field(default_factory=Numbering)
    started_ns: int = 0  # monotonic time the engine started
    body_seen: dict = field(default_factory=dict)  # body id -> newest sensor time (ns) it was in a frame
    newest_t_ns: int | None = None
    dropped: int = 0  # input frames shed since the last live frame went out
    restarted: bool = False  # this engine replaced one of the same stream (restart cooldown applies)

    def note_arrival(self, time_ns: int, arrival_ns: int) -> None:
        index = self.base_index + len(self.by_index)
        self.arrivals[time_ns] = (arrival_ns, index)
        self.by_index.append(arrival_ns)
        self.last_arrival_ns = arrival_ns
        while len(self.arrivals) > _MAX_PENDING:
            self.arrivals.popitem(last=False)
        while len(self.by_index) > _MAX_PENDING + self.lookahead:
            self.by_index.popleft()
            self.base_index += 1

    def arrival_of(self, time_ns: int) -> int | None:
        got = self.arrivals.get(time_ns)
        return None if got is None else got[0]

    def clean_out(self, time_ns: int) -> tuple[int | None, int | None]:
        """Arrival of this frame and of the frame ``lookahead`` later (None if unknown)."""
        got = self.arrivals.pop(time_ns, None)
        if got is None:
            return None, None
        arrival, index = got
        k = index + self.lookahead - self.base_index
        trigger = self.by_index[k] if 0 <= k < len(self.by_index) else None
        # input frames before the oldest pending one are no longer needed as triggers
        oldest = next(iter(self.arrivals.values()), (0, index + 1))[1]
        while self.by_index and self.base_index < min(oldest, index + 1):
            self.by_index.popleft()
            self.base_index += 1
        return arrival, trigger


class Service:
    """Run a source through per-stream engines onto a publisher (see module docstring)."""

    def __init__(
        self,
        source,
        publisher: ServicePublisher,
        make_engine: Callable[[Skeleton, float], object],
        *,
        default_rate_hz: float = 30.0,
        metrics: ServiceMetrics | None = None,
        metrics_port: int | None = None,
        metrics_host: str = "127.0.0.1",
        status_interval_s: float = 5.0,
        status_stream=None,
        status_at_exit: bool = False,
        max_log_per_s: int = 20,
        flush_timeout_s: float = 10.0,
        start_delay_s: float = 0.0,
        idle_timeout_s: float = 0.0,
        limits: Limits | None = None,
        sinks: tuple = (),
    ) -> None:
        self.source = source
        self.sinks = list(sinks)  # extra outputs (VMC, LSL: streamfix.service.sinks), best effort
        self.publisher = publisher
        self.make_engine = make_engine
        self.default_rate_hz = float(default_rate_hz)
        self.flush_timeout_s = float(flush_timeout_s)
        self.start_delay_s = float(start_delay_s)
        self.idle_timeout_s = float(idle_timeout_s)
        self.limits = limits or getattr(source, "limits", None) or Limits()
        self.m = metrics or ServiceMetrics()
        self.metrics_server: MetricsServer | None = None
        if metrics_port is not None:
            self.metrics_server = MetricsServer(self.m.registry, metrics_port, metrics_host).start()
        self.status_interval_s = float(status_interval_s)
        self.status_at_exit = bool(status_at_exit) or self.status_interval_s > 0
        self.status_stream = status_stream if status_stream is not None else sys.stderr
        self.streams: dict[str, _Stream] = {}
        # announced layouts, scoped per stream (shared with a ZeroMQ source, which decodes with them)
        scope = getattr(source, "scope", None)  # (an empty scope is falsy: test for None)
        self.scope: SkeletonScope = scope if scope is not None else SkeletonScope(self.limits)
        self._scope_forgotten = 0
        self._numbering: "OrderedDict[str, Numbering]" = OrderedDict()
        self._ended_labels: "OrderedDict[str, None]" = OrderedDict()
        # layouts a replayed file brings (not announced by any producer)
        self._replay_skeletons: dict[str, Skeleton] = dict(getattr(source, "skeletons", {}) or {})
        backlog = getattr(source, "backlog", None)
        self._max_age_ns = getattr(backlog, "max_age_ns", None)  # shedding policy of a ZeroMQ source
        self._stop = threading.Event()
        self._poll_start = 0  # the stream whose engine _poll_engines polls first
        self._max_log_per_s = int(max_log_per_s)
        self._log_window = (0.0, 0)
        self._suppressed = 0
        self._started = time.monotonic()
        self._last_status = (self._started, 0)

    # ------------------------------------------------------------------ control
    def stop(self, *_: object) -> None:
        """Ask the loop to finish (signal-safe); pending frames are still flushed.

        A second request while the first is being served (e.g. Ctrl-C twice during a
        long flush) gives up on the flush: KeyboardInterrupt, exit status 130.
        """
        if self._stop.is_set():
            raise KeyboardInterrupt("second stop request: not waiting for the flush")
        self._stop.set()

    def install_signal_handlers(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self.stop)

    # ------------------------------------------------------------------ logging
    def _log_limited(self, text: str, *args: object) -> None:
        """One warning line, at most ``max_log_per_s`` per second (the rest are summed)."""
        now = time.monotonic()
        start, n = self._log_window
        if now - start >= 1.0:
            if self._suppressed:
                log.warning("%d more input problems in the last second were counted but not logged", self._suppressed)
            self._log_window, self._suppressed = (now, 0), 0
            start, n = now, 0
        if n < self._max_log_per_s:
            log.warning(text, *args)
            self._log_window = (start, n + 1)
        else:
            self._suppressed += 1

    def _reject(self, reason: str, detail: str) -> None:
        self.m.malformed.inc(reason=reason)
        self._log_limited("skipped malformed input (%s): %s", reason, short(detail, 300)[1:-1])

    def _limit(self, limit: str, detail: str, n: int = 1) -> None:
        self.m.limit_hits.inc(n, limit=limit)
        self._log_limited("limit %s: %s", limit, short(detail, 300)[1:-1])

    # ------------------------------------------------------------------ input
    def _handle(self, item) -> None:
        if isinstance(item, Frame):
            self._handle_frame(item)
        elif isinstance(item, Rejected):
            self._reject(item.reason, item.detail)
        elif isinstance(item, Limited):
            self._limit(item.limit, item.detail)
        elif isinstance(item, Shed):
            self._shed(item)
        elif isinstance(item, Announce):
            if not item.registered:
                try:
                    self.scope.announce(item.stream_id, item.skeleton, item.rate_hz)
                except LimitHit as exc:
                    self._limit(exc.limit, exc.detail)

    def _shed(self, item: Shed) -> None:
        self.m.shed.inc(item.count, reason=item.reason)
        st = self.streams.get(item.stream_id) if item.stream_id is not None else None
        if st is not None:
            st.dropped += item.count
        if item.reason == "shutdown":
            log.warning("shutdown: %d input frames of stream %s were received but not processed (dropped)",
                        item.count, short(item.stream_id, 70))
        else:
            self._log_limited("overload: shed %d input frames of stream %s (backlog bound)",
                              item.count, short(item.stream_id, 70))

    def _skeleton_of(self, frame: SkeletonFrame) -> Skeleton | None:
        return self.scope.table(frame.stream_id).get(frame.skeleton) or self._replay_skeletons.get(frame.skeleton)

    def _numbering_of(self, stream_id: str) -> Numbering:
        num = self._numbering.pop(stream_id, None) or Numbering()
        self._numbering[stream_id] = num  # most recently used last
        while len(self._numbering) > _MAX_NUMBERINGS:
            self._numbering.popitem(last=False)
        return num

    def _stream_for(self, frame: SkeletonFrame, rate_hint: float | None) -> _Stream | None:
        """The frame's stream, started or restarted as needed; None if the frame is skipped."""
        st = self.streams.get(frame.stream_id)
        cause = None
        if st is not None:
            if st.skeleton.name != frame.skeleton:
                cause, why = "skeleton_change", f"switched skeleton {st.skeleton.name} -> {short(frame.skeleton, 40)}"
            elif st.last_seq is not None and st.last_seq - int(frame.seq) > max(30, int(st.rate_hz)):
                # seq jumped back by more than ~1 s: the sender restarted (the engine would
                # otherwise skip every frame as late until seq caught up)
                cause, why = "producer_restart", f"restarted (seq {frame.seq} after {st.last_seq})"
            elif st.newest_t_ns is not None and st.newest_t_ns - int(frame.sensor_time_ns) > _CLOCK_RESET_NS:
                back_s = (st.newest_t_ns - int(frame.sensor_time_ns)) / 1e9
                cause, why = "clock_reset", f"restarted (sensor time went back {back_s:.3g} s)"
            else:
                return st
            if st.restarted and time.monotonic_ns() - st.started_ns < self.limits.restart_cooldown_s * 1e9:
                # two producers on one stream id would restart it on every frame: at most one
                # restart per cooldown; the other frames are skipped (and counted)
                self._limit("restart", f"stream {frame.stream_id!r} seq {frame.seq}: {why} within "
                                       f"{self.limits.restart_cooldown_s:g} s of its last start (duplicate producer?)")
                return None
            self._retire(st, why)
        elif len(self.streams) >= self.limits.max_streams:
            self._limit("streams", f"stream {short(frame.stream_id, 70)}: {len(self.streams)} streams are "
                                   f"running, at most {self.limits.max_streams} (serve --max-streams)")
            return None
        skeleton = self._skeleton_of(frame) or get_skeleton(frame.skeleton)
        rate = rate_hint or self.scope.rate(frame.stream_id, skeleton.name) or self.default_rate_hz
        try:
            rate = check_rate(frame.stream_id, rate, self.limits)
        except LimitHit as exc:
            self._limit(exc.limit, exc.detail)
            return None
        try:
            engine = self.make_engine(skeleton, float(rate))
        except ValueError as exc:  # e.g. a window too short for this stream's rate
            self._reject("invalid", f"stream {frame.stream_id!r}: cannot start an engine: {exc}")
            return None
        wake = getattr(self.source, "wake", None)
        if wake is not None and hasattr(engine, "on_window_done"):
            engine.on_window_done = wake  # clean frames go out when their window is solved, not next turn
        numbering = self._numbering_of(frame.stream_id)
        numbering.restart()
        if cause is not None:
            self.m.restarts.inc(cause=cause)
        st = _Stream(frame.stream_id, skeleton, float(rate), engine, numbering=numbering,
                     started_ns=time.monotonic_ns(), restarted=cause is not None)
        try:
            st.lookahead = int(engine.metrics().get("lookahead_frames", 0))
        except Exception:
            st.lookahead = 0
        self.streams[frame.stream_id] = st
        self.scope.activate(frame.stream_id)
        self._ended_labels.pop(frame.stream_id, None)
        self.publisher.announce(frame.stream_id, skeleton, float(rate))
        log.info("new stream %r: skeleton %s (%d joints), %.3g Hz, epoch %d",
                 frame.stream_id, skeleton.name, skeleton.n_joints, rate, numbering.epoch)
        return st

    def _retire(self, st: _Stream, why: str, level: int = logging.WARNING, *, flush: bool = True) -> None:
        """Flush (unless failed) and close a stream's engine; its pending frames still go out."""
        log.log(level, "stream %r %s: %s its engine", st.stream_id, why, "flushing" if flush else "discarding")
        if self.streams.get(st.stream_id) is st:
            del self.streams[st.stream_id]
        if flush:
            self._guard(st, "flush", lambda: self._publish_outputs(st, self._engine_flush(st)))
        try:
            close = getattr(st.engine, "close", None)
            if close is not None:
                close()
        except Exception as exc:  # closing must not take the service down either
            log.warning("stream %r: closing its engine failed: %s", st.stream_id, exc)

    def _reclaim(self, st: _Stream, why: str) -> None:
        """A stream ended: retire it and forget its layouts, meta repeats and (eventually) labels."""
        self._retire(st, why, logging.INFO)
        self.scope.forget(st.stream_id)
        self.publisher.forget(st.stream_id)
        self._ended_labels[st.stream_id] = None
        while len(self._ended_labels) > _MAX_STREAM_LABELS:
            old, _ = self._ended_labels.popitem(last=False)
            self.m.frames_in.remove(stream=old)

    def _guard(self, st: _Stream, stage: str, fn: Callable[[], None]) -> bool:
        """Run one stream's step; an exception is contained (:meth:`_fail`). True if it ran."""
        try:
            fn()
            return True
        except Exception as exc:  # MemoryError included: contained to this stream
            self._fail(st, stage, exc)
            return False

    def _fail(self, st: _Stream, stage: str, exc: BaseException) -> None:
        """Count and log a stream's failure; discard its engine (the next frame starts a new epoch)."""
        self.m.failures.inc(stage=stage)
        self._log_limited("stream %r failed in %s (%s: %s); its engine is discarded, its next frame "
                          "starts it afresh", st.stream_id, stage, type(exc).__name__, short(str(exc), 200)[1:-1])
        if stage != "flush" and self.streams.get(st.stream_id) is st:
            self._retire(st, f"failed in {stage}", flush=False)
            self.m.restarts.inc(cause="failure")

    def _admit_bodies(self, st: _Stream, frame: SkeletonFrame) -> None:
        """Drop bodies with new ids beyond the per-stream / total limits (counted)."""
        t = int(frame.sensor_time_ns)
        st.newest_t_ns = t if st.newest_t_ns is None else max(st.newest_t_ns, t)
        ttl = self.limits.body_ttl_s * 1e9
        seen = st.body_seen
        if len(seen) >= self.limits.max_bodies_per_stream // 2:  # prune only when it matters
            for bid in [b for b, tb in seen.items() if st.newest_t_ns - tb > ttl]:
                del seen[bid]
        kept = []
        refused = 0
        cost = st.skeleton.n_joints * st.rate_hz  # joint-samples per second one more body adds
        for body in frame.bodies:
            if body.body_id not in seen:
                total = sum(len(s.body_seen) for s in self.streams.values())
                load = sum(len(s.body_seen) * s.skeleton.n_joints * s.rate_hz for s in self.streams.values())
                if (len(seen) >= self.limits.max_bodies_per_stream or total >= self.limits.max_bodies_total
                        or load + cost > self.limits.max_joint_rate):
                    refused += 1
                    continue
            seen[body.body_id] = t
            kept.append(body)
        if refused:
            frame.bodies = kept
            self._limit("bodies_stream", f"stream {frame.stream_id!r} seq {frame.seq}: {refused} new body ids "
                                         f"refused ({len(seen)} tracked, at most {self.limits.max_bodies_per_stream} "
                                         f"per stream, {self.limits.max_bodies_total} in all, and "
                                         f"{self.limits.max_joint_rate:g} joints x Hz in all)", refused)

    def _handle_frame(self, item: Frame) -> None:
        frame = item.frame
        if (self._max_age_ns is not None and not item.newest
                and time.monotonic_ns() - item.arrival_ns > self._max_age_ns):
            # it waited beyond the backlog bound while earlier frames were handled, and a later
            # frame of its stream is at hand: shed it too
            self._shed(Shed(frame.stream_id, 1))
            return
        try:
            check_stream_id(frame.stream_id)
            if len(frame.bodies) > self.limits.max_bodies_per_frame:
                raise LimitHit("bodies_frame", f"stream {frame.stream_id!r} seq {frame.seq}: {len(frame.bodies)} "
                                               f"bodies, at most {self.limits.max_bodies_per_frame}")
            skel = self._skeleton_of(frame)
            frame, nonfinite = validate_frame(frame, {skel.name: skel} if skel is not None else None)
        except WireError as exc:
            self._reject("invalid", str(exc))
            return
        except BadInput as exc:
            self._reject(exc.reason, exc.detail)
            return
        except LimitHit as exc:
            self._limit(exc.limit, exc.detail)
            return
        if nonfinite:
            self.m.nonfinite.inc(nonfinite)
        far = limit_coordinates(frame, self.limits.max_coordinate_m)
        if far:
            self._limit("coordinate", f"stream {frame.stream_id!r} seq {frame.seq}: {far} joints beyond "
                                      f"{self.limits.max_coordinate_m:g} m treated as missing", far)
        st = self._stream_for(frame, item.rate_hz)
        if st is None:
            return
        self._admit_bodies(st, frame)
        t0 = time.perf_counter()
        try:
            # after shed input the gap is the service's doing: filling it would redo the work shed
            outputs = st.engine.push(frame, fill=False) if st.dropped else st.engine.push(frame)
        except ValueError as exc:  # the engine refused the frame (e.g. a duplicate body id)
            self._reject("invalid", str(exc))
            return
        except Exception as exc:  # contained: counted, this stream restarts
            self._fail(st, "engine", exc)
            return
        compute = time.perf_counter() - t0
        self.m.frames_in.inc(stream=frame.stream_id)
        st.frames += 1
        st.last_active_ns = time.monotonic_ns()  # handled now (it may have waited in the socket)
        st.last_seq = int(frame.seq)
        st.bodies = len(frame.bodies)
        if not self._guard(st, "output", lambda: self.publisher.publish("raw", frame)):
            return
        if outputs:  # an accepted frame always has its live output; a late one has none
            st.note_arrival(int(frame.sensor_time_ns), item.arrival_ns)
            self.m.live_compute.observe(compute)
        self._guard(st, "output", lambda: self._publish_outputs(st, outputs))

    # ------------------------------------------------------------------ output
    def _publish_outputs(self, st: _Stream, outputs) -> None:
        """Number (epoch, seq) and publish a stream's outputs; observe latencies from arrival."""
        if not outputs:
            return
        for kind, out in outputs:
            epoch, seq = st.numbering.wire(int(out.seq))
            dropped = 0
            if kind == "live" and st.dropped:
                dropped, st.dropped = st.dropped, 0
            self.publisher.publish(kind, dataclasses.replace(out, seq=seq, epoch=epoch, dropped=dropped))
            for sink in self.sinks:
                try:
                    sink.send(kind, out, st.skeleton, st.rate_hz)
                except Exception as exc:  # a sink must not cost the ZeroMQ output or the engine
                    self._log_limited("stream %r: %s output failed: %s", st.stream_id, type(sink).__name__, exc)
            if out.filled:
                if kind == "clean":
                    self.m.filled.inc()
                continue
            now = time.monotonic_ns()
            t = int(out.sensor_time_ns)
            if kind == "live":
                arrival = st.arrival_of(t)
                if arrival is not None:
                    self.m.live_latency.observe((now - arrival) / 1e9)
            elif kind == "clean":
                arrival, trigger = st.clean_out(t)
                if arrival is not None:
                    self.m.clean_latency.observe((now - arrival) / 1e9)
                if trigger is not None:
                    self.m.clean_compute.observe(max(0.0, (now - trigger) / 1e9))

    def _retire_idle(self) -> None:
        """Reclaim streams that sent nothing for ``idle_timeout_s``: their last frames come out."""
        if self.idle_timeout_s <= 0:
            return
        now = time.monotonic_ns()
        for st in list(self.streams.values()):
            if now - st.last_active_ns > self.idle_timeout_s * 1e9:
                self._reclaim(st, f"sent nothing for {self.idle_timeout_s:g} s")

    def _poll_engines(self) -> None:
        """Each engine's background output (clean frames), until input is waiting, so a
        live frame does not wait behind other streams' clean work: the engines not polled
        are the first polled on the next turn, and every turn polls at least one, so input
        that keeps coming delays no engine's clean frames by more than a turn per stream."""
        streams = list(self.streams.values())
        pending = getattr(self.source, "pending", None)
        start = self._poll_start % len(streams) if streams else 0
        for i in range(len(streams)):
            if i:
                _yield_cpu()
                if pending is not None and pending()[0]:
                    self._poll_start = start + i
                    return
            st = streams[(start + i) % len(streams)]
            poll = getattr(st.engine, "poll", None)
            if poll is not None:
                self._guard(st, "engine", lambda: self._publish_outputs(st, poll()))

    def _sync_counters(self) -> None:
        for kind in ("raw", "live", "clean", "meta"):
            sent = self.publisher.counters.get(kind, 0)
            delta = sent - self.m.frames_out.value(topic=kind)
            if delta > 0:
                self.m.frames_out.inc(delta, topic=kind)
            dropped = self.publisher.drops.get(kind, 0)
            delta = dropped - self.m.drops.value(topic=kind)
            if delta > 0:
                self.m.drops.inc(delta, topic=kind)
        forgotten = self.scope.forgotten - self._scope_forgotten
        if forgotten > 0:
            self.m.limit_hits.inc(forgotten, limit="announcements")
            self._scope_forgotten = self.scope.forgotten
        cut = getattr(self.source, "disconnects", 0) - self.m.disconnects.value()
        if cut > 0:
            self.m.disconnects.inc(cut)
        pending = getattr(self.source, "pending", None)
        if pending is not None:
            n, age = pending()
            self.m.backlog.set(n)
            self.m.backlog_age.set(age)
        self.m.bodies.set(sum(st.bodies for st in self.streams.values()))
        self.m.streams.set(len(self.streams))
        degraded, level = False, 0
        for st in self.streams.values():
            try:
                em = st.engine.metrics()
            except Exception:  # metrics must never take the service down
                continue
            degraded |= bool(em.get("degraded", False))
            level = max(level, int(em.get("degrade_level", 0) or 0))
            late = int(em.get("frames_dropped_late", 0))
            if late > st.late_seen:
                self.m.late.inc(late - st.late_seen)
                self._log_limited("stream %s: skipped %d input frames out of order (seq or sensor time not "
                                  "after the previous frame's)", short(st.stream_id, 70), late - st.late_seen)
                st.late_seen = late
            for event in _ENGINE_EVENTS:
                n = int(em.get(event, 0) or 0)
                if n > st.events_seen.get(event, 0):
                    self.m.engine_events.inc(n - st.events_seen.get(event, 0), event=event)
                    st.events_seen[event] = n
        self.m.degraded.set(1.0 if degraded else 0.0)
        self.m.degrade_level.set(level)

    def status_line(self) -> str:
        """One line: uptime, input rate, outputs, malformed, limits, shed, drops, bodies, latencies, degraded."""
        now = time.monotonic()
        total_in = int(sum(self.m.frames_in.values().values()))
        t_prev, n_prev = self._last_status
        rate = (total_in - n_prev) / max(now - t_prev, 1e-9)
        self._last_status = (now, total_in)
        malformed = sum(self.m.malformed.values().values())
        limits = sum(self.m.limit_hits.values().values())
        shed = sum(self.m.shed.values().values())
        drops = sum(self.m.drops.values().values())
        late = self.m.late.value()

        def ms(h) -> str:
            q = h.quantile(0.99)
            return "-" if q != q else f"{q * 1e3:.1f}ms"

        return (
            f"streamfix serve: up {now - self._started:.0f}s | in {total_in} ({rate:.1f}/s) | "
            f"live {self.m.frames_out.value(topic='live'):.0f} clean {self.m.frames_out.value(topic='clean'):.0f} | "
            f"malformed {malformed:.0f} | limits {limits:.0f} | shed {shed:.0f} | drops {drops:.0f} | late {late:.0f} | "
            f"streams {len(self.streams)} bodies {self.m.bodies.value():.0f} | live p99 {ms(self.m.live_latency)} "
            f"clean+ p99 {ms(self.m.clean_compute)} | degraded {'YES' if self.m.degraded.value() else 'no'}"
        )

    def _status(self, force: bool = False) -> None:
        if self.status_interval_s <= 0 and not force:
            return
        print(self.status_line(), file=self.status_stream, flush=True)

    # ------------------------------------------------------------------ loop
    def run(self, *, max_turn_s: float = 0.01, drain_timeout_s: float = 2.0) -> int:
        """Serve until stopped or the source ends; flush; close. Returns the exit code (0)."""
        next_status = time.monotonic() + self.status_interval_s
        next_sync = 0.0
        start_at = time.monotonic() + self.start_delay_s
        while not self._stop.is_set() and time.monotonic() < start_at:
            time.sleep(min(0.05, max(0.0, start_at - time.monotonic())))  # let subscribers connect first
        try:
            while not self._stop.is_set():
                items = self.source.poll(max_turn_s)
                self._handle_input(items, max_turn_s)
                self._poll_engines()
                now = time.monotonic()
                self._guard_tick(now)
                if now >= next_sync:
                    if not items:  # only with the input drained: a busy service is not an idle stream
                        self._retire_idle()
                    self._sync_counters()
                    next_sync = now + 0.25
                if self.status_interval_s > 0 and now >= next_status:
                    self._sync_counters()
                    self._status()
                    next_status = now + self.status_interval_s
                if self.source.exhausted:
                    break
            self._drain(drain_timeout_s)
            self._flush()
        finally:
            self._sync_counters()
            self._status(force=self.status_at_exit)
            self.close()
        return 0

    def _handle_input(self, items: list, max_s: float) -> None:
        """Handle ``items`` and what arrives meanwhile, for up to ``max_s`` s, before the
        engines' background work: their windows go to the solver when the engines are polled
        (:meth:`StreamEngine.poll`), so the frames of every stream that arrived together have
        their live output out before a solve competes with them for the core."""
        pending = getattr(self.source, "pending", None)
        deadline = time.monotonic() + max_s
        while items:
            for item in items:
                self._handle(item)
                _yield_cpu()  # the ZeroMQ threads: the next frame in, this one's live frame out
            if pending is None or pending()[0] == 0 or time.monotonic() >= deadline:
                return
            items = self.source.poll(0.0)

    def _guard_tick(self, now: float) -> None:
        try:
            self.publisher.tick(now)
        except Exception as exc:  # a meta message that cannot be sent must not stop the loop
            self.m.failures.inc(stage="output")
            self._log_limited("repeating skeleton messages failed: %s", short(str(exc), 200))

    def _drain(self, timeout_s: float) -> None:
        """Handle what the source already holds, for at most ``timeout_s``; count the rest as shed."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            items = self.source.poll(0.0)
            if not items:
                break
            for item in items:
                self._handle(item)
        drop = getattr(self.source, "drop_pending", None)
        if drop is not None:
            for item in drop():
                self._handle(item)

    def _flush(self) -> None:
        for st in list(self.streams.values()):
            self._poll_engines()
            self._guard(st, "flush", lambda: self._publish_outputs(st, self._engine_flush(st)))
            try:
                close = getattr(st.engine, "close", None)
                if close is not None:
                    close()
            except Exception as exc:
                log.warning("stream %r: closing its engine failed: %s", st.stream_id, exc)

    def _engine_flush(self, st: _Stream):
        return st.engine.flush(timeout=self.flush_timeout_s)

    def close(self) -> None:
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as exc:
                log.warning("closing %s failed: %s", type(sink).__name__, exc)
        self.publisher.close()
        self.source.close()
        if self.metrics_server is not None:
            self.metrics_server.close()
