"""The streaming engine: frames in, a causal ``live`` and a refined ``clean`` stream out.

No sockets here: :class:`StreamEngine` consumes :class:`~streamfix.frames.SkeletonFrame`
objects and returns ``(kind, frame)`` pairs, ``kind`` in ``{'live', 'clean'}``.
``streamfix serve`` wires it to ZeroMQ; ``streamfix clean`` runs recorded files through
the very same engine in synchronous mode, on a schedule made for files
(:meth:`EngineConfig.for_files`; with ``serve``'s schedule the two agree exactly).

Windows, hop, lookahead and overlap-add
---------------------------------------
Per body, frames are numbered ``n = 0, 1, ...`` from the body's first frame (its
*timeline*; it also advances while the body is briefly absent, see below). With
window ``W``, hop ``H`` and lookahead ``L`` (frames, ``1 <= H <= L + 1 <= W``):

* window ``k`` ends at ``e_k = L + 1 + k H`` (exclusive) and covers frames
  ``[max(0, e_k - W), e_k)``; while the body's first ``W`` frames arrive, windows also
  end every ``startup_hop`` frames between those (:func:`~streamfix.streaming.blending.next_window_end`:
  the short first windows disagree most, and then share more frames); it is solved as
  soon as frame ``e_k - 1`` has arrived,
  warm-started from the previous window's solver state shifted by the hop
  (``state.shifted(e_k - e_{k-1})``) when both windows have the full length ``W``
  (a state with per-frame memory, the frozen-limb release, is ``reframed`` onto windows
  of other lengths, without the warm start);
* the solution of window ``k`` is blended into every not-yet-emitted frame it covers
  with a weight that depends on how many of the window's frames lie after the frame
  (:func:`handover_weights`: a short crossfade at each hand-over, so a window's arrival
  does not step the output), normalised per frame: the clean value of
  frame ``n`` is ``sum_k w_k x_k / sum_k w_k`` over the windows ``k`` with
  ``n < e_k <= n + L + 1``, i.e. exactly the windows that have been solved when frame
  ``n + L`` arrives (there is at least one because ``H <= L + 1``). The weights
  therefore sum to 1 for every frame, and the mean is accumulated incrementally as
  ``m <- m + w / (sum w) (x - m)``, so a window solver that returns its input leaves
  the input unchanged bit for bit. A sample a window released as the sensor's frozen
  guess (its ``info[RELEASED_KEY]``) drops what older windows that kept it blended: they
  saw too little of the frozen run to judge it and kept the sensor's pose
  (:func:`~streamfix.streaming.overlap_add.blend_window`); likewise a gap's sample a window
  saw end (the joint observed later in it) drops what older windows blended while the gap
  was open (:func:`~streamfix.streaming.overlap_add.closed_gaps`).
* where the windows report sensor noise (their ``info[NOISE_SHARE_KEY]``, blended like
  the positions; ``clean_window``'s stage-3 gate), the blended values are then smoothed
  over time by a short kernel that keeps quadratic motion (``output_smooth_s``,
  :func:`~streamfix.streaming.overlap_add.smooth_output`): the hand-overs and the bone projection leave
  frame-to-frame jitter that no single window sees. The kernel's future frames are the
  newest window's values, so this adds no latency; exact data is left as blended.
* frame ``n`` is emitted on ``clean`` when frame ``n + L`` has been pushed: the
  **latency is fixed at L frame periods (L / rate_hz s) plus the window's compute
  time**, and in steady state every push emits exactly one clean frame. At shutdown
  (:meth:`StreamEngine.flush`) or when a body times out, a last window ending at the
  body's newest frame is solved and the remaining frames are emitted with less
  lookahead.

Each window's first ``W - L - 1`` frames are context only (already emitted); a frame's
value comes from windows that saw between ``L + 1 - H`` and ``L`` frames of its future.
Defaults (seconds, converted at ``rate_hz``): W 2 s, H 1/3 s, L 0.5 s = 60/10/15 frames
at 30 Hz. The frames with the least future context (``L + 1 - H``) sit inside the
solver's edge effects, so a longer hop costs accuracy (``tests/test_e2e_quality.py``
holds the clean output within 1.25x of the whole-take solve). Compute is one window solve per
body per ``H`` frames, so bodies per core scale with ``H / W`` and the window solver's
cost: ``benchmarks/bench_streaming.py`` measures it against a Savitzky-Golay window.

Offline cleaning is a pure function of the input sequence: in the synchronous mode
(the default) nothing depends on timing, so the same input gives the same output.

Bodies
------
A body (``BodyFrame.body_id``) appears with its first frame. While it is absent from
the stream its timeline keeps advancing with all-missing frames (the solver bridges
them), for up to ``body_timeout_s``; within that grace period a returning body is the
same body. After it, the body is finalised (its pending frames are emitted) and
forgotten; if the same id returns later it starts a new timeline, re-using the bone
lengths estimated for it before (``bodies_reidentified`` counts these). The clean and
live output of a frame hold exactly the bodies of the input frame, in input order.
Output confidence is the sensor's for observed joints and 0.5 (``RECOVERED_CONFIDENCE``,
"estimated") for joints the engine recovered (``recovered`` True); a joint the engine
has no value for at all (never seen) is NaN with confidence 0.

Long gaps (the default window solver)
-------------------------------------
:func:`default_window_solver` is :class:`~streamfix.streaming.bridging.BridgingWindowSolver`
around ``clean_window``: in a window, a joint missing for ``>= ceil(W/3)`` frames (or the
whole window) and runs of ``>= 3`` frames with fewer than 3 observed joints are filled
first -- by PCA (Li et al.) trained on the body's own clean history (the last
``HISTORY_S`` = 10 s of clean output, observed samples only, passed as ``history=`` to
solvers with ``wants_history``) once 3 s of it exist, else by the learned prior's D(z*)
(Kinect v2) -- and flagged ``recovered``. Other windows go to ``clean_window``
unchanged. ``metrics()`` counts the bridged joint-frames by source
(``joints_bridged_time`` / ``_pca`` / ``_prior`` / ``_hold``) and sources that failed on a window
(``bridge_errors``; the next source is tried).

Dropped sensor frames and sequence numbers
------------------------------------------
A gap between consecutive sensor timestamps larger than ``drop_gap_factor`` (1.5)
frame periods means the sensor dropped ``round(gap * rate_hz) - 1`` frames. The
engine synthesises them (evenly spaced timestamps, the bodies of the frame before
the gap, every joint ``recovered``) with ``SkeletonFrame.filled =
True`` and emits them on ``live`` and ``clean`` like any frame, so the output has no
holes. Gaps longer than ``max_fill_s`` are a discontinuity, not a drop: the bodies
are finalised and the stream restarts, nothing is synthesised.

**Sequence numbers of output frames**: the output of a stream is numbered
consecutively, ``seq = seq0 + k``, where ``seq0`` is the ``seq`` of the stream's first
input frame and ``k`` counts the frames the engine has produced for the stream (real
and filled, in order). The same frame has the same ``seq`` on ``live`` and ``clean``.
Without drops, output ``seq`` equals input ``seq``; after ``f`` filled frames, a real
frame's output ``seq`` is its input-order index plus ``seq0`` (input ``seq`` values are
only used to reject duplicates and reordered frames). Real frames keep their
``sensor_time_ns``, so a subscriber can always match input and output on it.
A frame whose ``seq`` is not greater than the previous one's, or whose sensor time
goes backwards, is late: it is counted (``frames_dropped_late``) and skipped.

Degradation (threaded mode)
---------------------------
:class:`ThreadedStreamEngine` solves windows in the process's shared pool of solver
threads (:mod:`streamfix.streaming.solver_pool`: one FIFO for every engine, a thread per
CPU); ``push`` never waits for it. When the solver falls behind (a window is scheduled
while another is still pending, or the last solve took longer than the hop duration
``H / rate_hz``) the engine degrades one level at a time: 1 = half the solver iterations, 2 = also twice
the hop, 3 = quarter iterations and the largest hop (``max_hop``). It recovers a level
after ``recover_after`` consecutive healthy windows. When more than
``max_pending_windows`` windows are queued a new window is skipped; when a frame
has waited ``max_clean_delay_s`` beyond its lookahead for a stalled window, that
window is abandoned. A window whose solver raises is counted (``solver_errors``; the
first message is ``metrics()['first_solver_error']``: offline cleaning refuses a recording
whose every window failed, see :func:`streamfix.streaming.offline.clean_motion`). Frames
no solved window covers fall back to their ``live`` value (flagged recovered where the
live path recovered them). Input is never
blocked or dropped; every input frame still appears once on ``clean``.
:meth:`StreamEngine.metrics` reports the level, hop, iterations and counters.

Where the parts live
--------------------
This module keeps the timeline: frames in, windows scheduled, frames finalised and
emitted, bodies appearing and leaving. The rest is one concept per module: the body and
stream records (:mod:`.bodies`), frame validation (:func:`streamfix.frames.check_frame`),
bone lengths (:mod:`.bone_lengths`), solving one window (:mod:`.window_job`),
overlap-add and output smoothing (:mod:`.overlap_add`, weights in :mod:`.blending`) and
the overload policy (:mod:`.degradation`).
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable, Sequence

import numpy as np

from ..core.filters import twiced_binomial_taps
from ..core.pose_bias import correction_gain
from ..core.pose_bias_live import LivePoseBias
from ..core.ray_depth import MAX_BONE_M
from ..frames import BodyFrame, SkeletonFrame, check_frame
from ..skeletons import CAMERA_SPACE_SKELETONS, Skeleton
from ..limbs import mirror_bones
from ..sensor_bias.shipped import resolve_sensor_bias
from .blending import HANDOVER_S, crossfade_frames, handover_weights, next_window_end
from .bone_lengths import LengthSources, length_sources
from .bodies import (  # the constants are re-exported: the engine's documented settings
    BONE_HISTORY_S,  # noqa: F401
    BONE_MEMORY_S,  # noqa: F401
    BONE_OWN_SUPPORT_S,  # noqa: F401
    BONE_SUPPORT_FRAMES,  # noqa: F401
    BONE_PEAK_SHARE,  # noqa: F401
    BONE_SUPPORT_TOL_M,  # noqa: F401
    GUESSED_SHARE_POOLED,  # noqa: F401
    HISTORY_S,  # noqa: F401
    RECOVERED_CONFIDENCE,  # noqa: F401
    Body,
    Job,
    PendingFrame,
    StreamState,
    hop_phase,
    output_confidence,
)
from .config import DEFAULT_HOP_S, DEFAULT_LOOKAHEAD_S, DEFAULT_WINDOW_S, EngineConfig  # noqa: F401
from .degradation import Degradation
from .finalise import final_end, finalise_frames
from .histogram import Histogram
from .live import LivePath
from .live_carry import WindowCarry
from .overlap_add import blend_window
from .solver_api import WindowOutput, WindowSolver
from .solver_pool import SolverPool, shared_pool
from .window_job import solve_job
from .window_solvers import (
    alm_window_solver,
    default_window_solver,
    import_solver_modules,
    wants,
    with_max_iterations,
    with_score_frames,
)

__all__ = [
    "EngineConfig",
    "StreamEngine",
    "ThreadedStreamEngine",
    "WindowOutput",
    "WindowSolver",
    "alm_window_solver",
    "default_window_solver",
    "handover_weights",
    "HANDOVER_S",
    "Histogram",
]


class StreamEngine:
    """Per-stream, per-body streaming cleaner (synchronous unless ``threaded``).

    ``push(frame)`` returns ``[('live', frame), ..., ('clean', frame), ...]``: one live
    frame per input frame (plus one per synthesised dropped frame), and the clean
    frames that left the lookahead. ``flush()`` emits every pending frame.
    ``window_solver``: see :data:`WindowSolver`; None = :func:`default_window_solver`.
    ``body_ordinals``: gives each new body its ordinal, which sets its window phase
    (:func:`~streamfix.streaming.bodies.hop_phase`); None = this engine's own count from 0,
    or, threaded, the shared solver pool's count over all its engines.
    ``on_window_done`` (attribute, threaded mode): called with no arguments from the solver
    thread each time one of this engine's windows leaves the pool, so a caller that sleeps
    between inputs can :meth:`poll` the clean frames at once.
    ``clean_on_poll`` (threaded mode): :meth:`push` returns the live frame only and leaves
    blending finished windows, finalising and emitting clean frames to :meth:`poll`, so a
    caller with several streams' frames to handle sends every live frame before any of that
    work (``serve``: otherwise the last of several streams arriving together waits for the
    others' clean work). A stream holds at most one frame undrained: a push that finds one
    drains it first.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        config: EngineConfig | None = None,
        window_solver: WindowSolver | None = None,
        *,
        threaded: bool | None = None,
        body_ordinals: Callable[[], int] | None = None,
        clean_on_poll: bool = False,
    ) -> None:
        self.skeleton = skeleton
        self.cfg = config if config is not None else EngineConfig()
        self.solver = window_solver if window_solver is not None else default_window_solver()
        self._history = wants(self.solver, "wants_history")
        self._pass_skeleton = wants(self.solver, "wants_skeleton")
        # the frames of a window the blend uses (its newest L + 1), the hop before them and the
        # crossfade: where the window solver scores its estimators (PipelineConfig.score_newest_frames)
        self._solver_config = with_score_frames(
            self.cfg.solver_config, self.cfg.lookahead + self.cfg.hop + crossfade_frames(self.cfg.handover_s, self.cfg.rate_hz),
            self.solver)
        self._mirror_bones = mirror_bones(skeleton)
        self._pose_bias = resolve_sensor_bias(self.cfg.sensor_bias, skeleton)
        self._bias_alpha = correction_gain(self.cfg.rate_hz)
        self.bones = skeleton.bone_array
        self.n_joints = skeleton.n_joints
        # the live topic removes the same bias, one frame at a time (compiled)
        self._live_bias = None if self._pose_bias is None else LivePoseBias(self._pose_bias, self.bones, self._bias_alpha)
        if self.cfg.bone_lengths is not None and len(self.cfg.bone_lengths) != skeleton.n_bones:
            raise ValueError(
                f"bone_lengths has {len(self.cfg.bone_lengths)} values, skeleton {skeleton.name!r} "
                f"has {skeleton.n_bones} bones"
            )
        self._fixed_lengths = (
            None if self.cfg.bone_lengths is None else np.asarray(self.cfg.bone_lengths, dtype=np.float64)
        )
        self.period_ns = 1e9 / self.cfg.rate_hz
        # frames a stalled window may hold back (bounded: it sizes the per-body buffers)
        self._backlog = int(min(round(self.cfg.max_clean_delay_s * self.cfg.rate_hz), 8 * self.cfg.window))
        self._timeout = max(1, int(round(self.cfg.body_timeout_s * self.cfg.rate_hz)))
        self.streams: dict[str, StreamState] = {}
        threaded = self.cfg.threaded if threaded is None else bool(threaded)
        self.threaded = threaded
        self.degradation = Degradation(self.cfg)
        # metrics
        self.counters: dict[str, int] = {
            k: 0
            for k in (
                "frames_in", "frames_rejected", "frames_dropped_late", "frames_filled",
                "live_out", "clean_out", "bodies_seen", "bodies_reidentified", "bodies_timed_out",
                "windows_scheduled", "windows_solved", "windows_skipped", "windows_abandoned",
                "solver_errors", "solver_iterations", "solver_not_converged", "joints_recovered",
                "gaps_not_filled", "degrade_events", "joints_live_fallback",
                "joints_bridged_time", "joints_bridged_pca", "joints_bridged_prior", "joints_bridged_hold",
                "bridge_errors",
            )
        }
        self.live_hist = Histogram()
        self.solve_hist = Histogram()
        self._last_iterations = 0
        self._first_solver_error: str | None = None  # what the first failed window raised
        self._output_taps = twiced_binomial_taps(self.cfg.output_smooth_frames)  # see overlap_add.smooth_output
        self._fill_taps = twiced_binomial_taps(self.cfg.fill_smooth_frames)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._inflight = 0  # submitted, not finished (threaded)
        self._done_total = 0
        self._pool: SolverPool | None = None
        # threaded: windows scheduled by the frame being pushed, handed to the pool by the next
        # poll() (or push, flush): after the caller has sent this frame's live output
        self._deferred: list[Job] = []
        # the service wakes its loop with it to poll() the clean frames now, not at its next turn
        self.on_window_done: Callable[[], None] | None = None
        self._learn_lengths = bool(len(self.bones)) and self._fixed_lengths is None
        # offline (synchronous, no live topic): nothing waits for a clean frame, so frames are
        # finalised and emitted in runs, when a window is due and at the end, not one per push
        # (the same values: every window still sees the state a per-push drain would leave)
        self._batch_clean = not threaded and not self.cfg.live_output
        self._clean_on_poll = bool(clean_on_poll) and bool(threaded)
        self._closed = False
        if threaded:
            import sys

            # The worker holds the GIL for stretches of small numpy calls; Python's default
            # 5 ms switch interval would then delay the live frame by up to 5 ms. 0.5 ms
            # keeps push() (the live path) responsive; process-wide, only ever lowered.
            if sys.getswitchinterval() > 0.0005:
                sys.setswitchinterval(0.0005)

            # compile / load the kernels and import the solver's lazy imports now: not on
            # the first live frame or window
            from ..core import kernels

            kernels.warm_up()
            import_solver_modules()
            self._pool = shared_pool()  # one FIFO of windows for every engine of the process
        # a new body's ordinal sets its window phase (bodies.hop_phase). Engines that share the
        # pool count their bodies together: counted per engine, the k-th body of every stream
        # got the same phase and their windows queued behind each other on the same frame
        # (bench_service: five 6-body streams put five windows on 6 of 10 frames and none on 4)
        # (None: this engine's own count, counters["bodies_seen"])
        self._body_ordinal = body_ordinals or (self._pool.next_body_ordinal if self._pool is not None else None)

    # ------------------------------------------------------------------ public API
    def push(self, frame: SkeletonFrame, fill: bool = True) -> list[tuple[str, SkeletonFrame]]:
        """Feed one input frame; returns live (always) and clean (when due) frames.

        ``fill=False``: the frames before this one were shed by the service under
        overload, so the timestamp gap is neither filled nor a discontinuity.
        """
        self._validate(frame)
        self._submit_deferred()  # a caller that pushes without polling still gets its windows solved
        out: list[tuple[str, SkeletonFrame]] = []
        st = self.streams.get(frame.stream_id)
        if st is None:
            st = self.streams[frame.stream_id] = StreamState(frame.stream_id, int(frame.seq))
        elif self._is_late(st, frame):
            self.counters["frames_dropped_late"] += 1
            return out
        self.counters["frames_in"] += 1
        # ---- dropped sensor frames
        if st.last_time_ns is not None and self.cfg.fill_drops and fill:
            gap_ns = int(frame.sensor_time_ns) - st.last_time_ns
            if gap_ns > self.cfg.drop_gap_factor * self.period_ns:
                if gap_ns > self.cfg.max_fill_s * 1e9:
                    self.counters["gaps_not_filled"] += 1
                    if self._batch_clean:
                        self._drain(st, out)  # what each push would have finalised, first
                    self._end_stream_bodies(st, out)
                else:
                    n_fill = max(1, int(round(gap_ns / self.period_ns)) - 1)
                    step = gap_ns / (n_fill + 1)
                    for k in range(1, n_fill + 1):
                        t_ns = st.last_time_ns + int(round(k * step))
                        self._advance(st, None, t_ns, out)
        st.last_in_seq = int(frame.seq)
        self._advance(st, frame, int(frame.sensor_time_ns), out)
        st.last_time_ns = int(frame.sensor_time_ns)
        if self.threaded and not self._clean_on_poll:  # windows of other streams may have finished too
            for other in self.streams.values():
                if other is not st:
                    self._drain(other, out)
        return out

    def push_many(self, frames: Sequence[SkeletonFrame],
                  out: list[tuple[str, SkeletonFrame]] | None = None) -> list[tuple[str, SkeletonFrame]]:
        """Feed frames in order: the outputs of :meth:`push` on each, appended to ``out``
        (a new list if None), which is returned.

        Offline (synchronous, no live output), runs of plain frames (the one body of an
        existing stream, in order, no drop to fill, no window due) are written into the
        ring and the body's rows as arrays, not one by one; anything else goes through
        :meth:`push`. A frame :meth:`push` would refuse raises the same error after the
        frames before it, whose outputs are then in ``out`` (pass a list to keep them).
        """
        out = [] if out is None else out
        i, n = 0, len(frames)
        while i < n:
            k = self._one_body_block(frames, i) if self._batch_clean else 0
            if k:
                block = frames[i:i + k]
                self._push_block(
                    block[0].stream_id, block[0].bodies[0].body_id,
                    np.stack([np.asarray(f.bodies[0].positions, dtype=np.float64) for f in block]),
                    np.stack([np.asarray(f.bodies[0].confidence, dtype=np.float64) for f in block]),
                    np.array([int(f.sensor_time_ns) for f in block], dtype=np.int64),
                    np.array([int(f.seq) for f in block], dtype=np.int64), out, block)
                i += k
            else:
                out.extend(self.push(frames[i]))
                i += 1
        return out

    def push_arrays(self, stream_id: str, body_id: int, positions: np.ndarray, confidence: np.ndarray,
                    times_ns: np.ndarray, seq0: int = 0,
                    out: list[tuple[str, SkeletonFrame]] | None = None) -> list[tuple[str, SkeletonFrame]]:
        """One body's frames as arrays, for files: the outputs of :meth:`push_many` on the frames
        ``SkeletonFrame(stream_id, seq0 + k, times_ns[k], skeleton, [BodyFrame(body_id,
        positions[k], confidence[k])])``, appended to ``out`` (a new list if None), which is returned.

        ``positions`` ``(n, J, 3)`` m, ``confidence`` ``(n, J)``, ``times_ns`` ``(n,)`` sensor
        time (ns). Offline, the runs :meth:`push_many` writes as arrays are slices of these,
        and no frame object is made for them: a file's frames as objects cost more than the
        bookkeeping they feed. Arrays of the wrong shape are refused before any frame is
        taken (ValueError naming the expected joint count).
        """
        out = [] if out is None else out
        J = self.n_joints
        pos = np.asarray(positions, dtype=np.float64)
        conf = np.asarray(confidence, dtype=np.float64)
        times = np.asarray(times_ns, dtype=np.int64)
        n = len(times)
        if times.ndim != 1 or pos.shape != (n, J, 3) or conf.shape != (n, J):
            raise ValueError(f"stream {stream_id!r} body {body_id}: expected {J} joints ({self.skeleton.name}) as "
                             f"({n}, {J}, 3) positions and ({n}, {J}) confidences for {n} times, got "
                             f"{pos.shape} and {conf.shape}")
        self._push_block(stream_id, body_id, pos, conf, times, seq0 + np.arange(n, dtype=np.int64), out)
        return out

    def flush(self, timeout: float | None = 10.0) -> list[tuple[str, SkeletonFrame]]:
        """Finalise every body of every stream and emit all pending clean frames.

        Threaded mode waits up to ``timeout`` s (None = forever) for the queued windows;
        windows still unsolved then are abandoned (their frames use the live value), so
        a stalled solver cannot hang a shutdown.
        """
        out: list[tuple[str, SkeletonFrame]] = []
        for st in self.streams.values():
            if self._batch_clean:
                self._drain(st, out)  # what each push would have finalised, first
            for body in list(st.bodies.values()):
                self._begin_end(st, body)
        if self.threaded:
            self._submit_deferred()
            deadline = None if timeout is None else time.monotonic() + timeout
            with self._cond:
                while self._inflight > 0:
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        break
                    self._cond.wait(remaining if remaining is not None else 0.5)
            for st in self.streams.values():
                for body in st.ending:
                    for job in body.jobs:
                        if job.status == "pending":
                            job.status = "abandoned"
                            self.counters["windows_abandoned"] += 1
        for st in self.streams.values():
            self._drain(st, out)
            if st.pending:  # cannot happen unless a body was lost: never hold frames back
                raise RuntimeError(f"stream {st.stream_id!r}: {len(st.pending)} frames left after flush")
        self.streams.clear()
        return out

    def poll(self) -> list[tuple[str, SkeletonFrame]]:
        """Clean frames whose windows finished in the background since the last call
        (threaded mode; always empty in synchronous mode). Never blocks.

        Threaded, it also hands the windows the last pushes scheduled to the solver pool:
        :meth:`push` defers them, so a solve does not start while the caller is still sending
        the frame's live output (``serve`` polls after publishing every frame it received)."""
        out: list[tuple[str, SkeletonFrame]] = []
        if self.threaded:
            self._submit_deferred()
            for st in self.streams.values():
                self._drain(st, out)
        return out

    def close(self) -> None:
        """Stop solving this engine's windows (threaded mode; queued ones are not solved and
        pending windows are not waited for) and close the window solver if it has resources
        to free (a solver process)."""
        self._closed = True
        self._submit_deferred()  # they are skipped (closed), and the in-flight count stays true
        close = getattr(self.solver, "close", None)
        if close is not None:
            close()

    def __enter__(self) -> "StreamEngine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def level(self) -> int:
        """Degradation level 0..3 (:class:`~streamfix.streaming.degradation.Degradation`)."""
        return self.degradation.level

    @property
    def hop(self) -> int:
        """The hop (frames) windows are scheduled with now (the configured one unless degraded)."""
        return self.degradation.hop

    def metrics(self) -> dict:
        """Counters, histograms and the degradation state (plain data)."""
        m: dict[str, Any] = dict(self.counters)
        m.update(
            bodies_active=sum(len(s.bodies) for s in self.streams.values()),
            streams=len(self.streams),
            pending_clean_frames=sum(len(s.pending) for s in self.streams.values()),
            pending_windows=self._inflight,
            degraded=self.level > 0,
            degrade_level=self.level,
            hop=self.hop,
            max_iterations=self.degradation.iterations(),
            last_iterations=self._last_iterations,
            first_solver_error=self._first_solver_error,
            window=self.cfg.window,
            lookahead_frames=self.cfg.lookahead,
            lookahead_s=self.cfg.latency_s,
            threaded=self.threaded,
            live_time=self.live_hist.snapshot(),
            solve_time=self.solve_hist.snapshot(),
        )
        return m

    # ------------------------------------------------------------------ validation
    def _validate(self, frame: SkeletonFrame) -> None:
        try:
            check_frame(frame, self.skeleton)
        except ValueError:
            self.counters["frames_rejected"] += 1
            raise

    def _is_late(self, st: StreamState, frame: SkeletonFrame) -> bool:
        if st.last_in_seq is not None and int(frame.seq) <= st.last_in_seq:
            return True
        return st.last_time_ns is not None and int(frame.sensor_time_ns) < st.last_time_ns

    # ------------------------------------------------------------------ per frame
    def _one_body_block(self, frames: Sequence[SkeletonFrame], i: int) -> int:
        """How many frames from ``frames[i]`` on are one body of one stream (the same body id,
        the only body of each frame) that :meth:`push` takes (the skeleton's shapes)."""
        first = frames[i]
        if len(first.bodies) != 1:
            return 0
        sid, bid = first.stream_id, first.bodies[0].body_id
        end = i
        while end < len(frames):  # by index: slicing the rest of the list for every block copies it
            frame = frames[end]
            if frame.stream_id != sid or len(frame.bodies) != 1 or frame.bodies[0].body_id != bid:
                break
            try:
                check_frame(frame, self.skeleton)
            except ValueError:
                break  # push() refuses it, counted
            end += 1
        return end - i

    def _push_block(self, stream_id: str, body_id: int, pos: np.ndarray, conf: np.ndarray, times: np.ndarray,
                    seqs: np.ndarray, out: list, frames: Sequence[SkeletonFrame] | None = None) -> None:
        """Frames of one body of one stream, as arrays (shapes checked): offline, runs of plain
        frames (:meth:`_plain_run`) into the ring and the body's rows at once (:meth:`_store_run`),
        every other frame through :meth:`push` (``frames[k]`` when given, else made from the arrays)."""
        i, n = 0, len(times)
        while i < n:
            run = self._plain_run(stream_id, body_id, times, seqs, i) if self._batch_clean else 0
            if run:
                self._store_run(self.streams[stream_id], pos[i:i + run], conf[i:i + run], times[i:i + run],
                                int(seqs[i + run - 1]))
                i += run
            else:
                frame = frames[i] if frames is not None else SkeletonFrame(
                    stream_id, int(seqs[i]), int(times[i]), self.skeleton.name, [BodyFrame(body_id, pos[i], conf[i])])
                out.extend(self.push(frame))
                i += 1

    def _plain_run(self, stream_id: str, body_id: int, times: np.ndarray, seqs: np.ndarray, i: int) -> int:
        """How many of a block's frames from ``i`` on :meth:`_store_run` may take (0: none): the
        stream exists and ``body_id`` is its only body, already tracked; the frames are in order,
        with no drop to fill and no window due."""
        st = self.streams.get(stream_id)
        if st is None or st.ending or len(st.bodies) != 1 or body_id not in st.bodies:
            return 0
        body = st.bodies[body_id]
        limit = max(0, body.next_end - body.count - 1)  # the frame that completes a window: push()
        t, q = times[i:i + limit], seqs[i:i + limit]
        if not len(t):
            return 0
        t_prev = np.concatenate([[t[0] if st.last_time_ns is None else st.last_time_ns], t[:-1]])
        q_prev = np.concatenate([[q[0] - 1 if st.last_in_seq is None else st.last_in_seq], q[:-1]])
        gap = t - t_prev
        max_gap = self.cfg.drop_gap_factor * self.period_ns if self.cfg.fill_drops else np.inf
        bad = np.flatnonzero((q <= q_prev) | (gap < 0) | (gap > max_gap))
        return int(bad[0]) if len(bad) else len(t)

    def _store_run(self, st: StreamState, positions: np.ndarray, confidence: np.ndarray, times: np.ndarray,
                   last_seq: int) -> None:
        """A run of plain frames of the stream's one body into the ring and the body's rows: the
        same ring rows, body rows and pending frames as :meth:`_advance` frame by frame, and no
        drain (none is due within the run)."""
        (bid, body), = st.bodies.items()
        n = len(times)
        self.counters["frames_in"] += n
        for t_ns in times.tolist():
            st.g += 1
            st.pending[st.g] = PendingFrame(st.seq0 + st.g, t_ns, False, [bid])
        st.last_present = [bid]
        st.last_in_seq, st.last_time_ns = int(last_seq), int(times[-1])
        n0 = body.count
        raw, conf, valid = body.ring.push_many(positions, confidence, times)
        rows = (n0 + np.arange(n)) % body.cap
        body.reuse_rows(rows)
        body.store_present(rows, n0 + n - 1, raw, conf, valid, np.nan, True)  # offline: no live path
        body.count = n0 + n

    def _advance(self, st: StreamState, frame: SkeletonFrame | None, t_ns: int, out: list) -> None:
        """Add one stream frame (``frame`` None = a synthesised dropped frame)."""
        st.g += 1
        g = st.g
        seq = st.seq0 + g
        if frame is None:
            present_ids = [bid for bid in st.last_present if bid in st.bodies]
            inputs: dict[int, BodyFrame] = {}
            self.counters["frames_filled"] += 1
        else:
            inputs = {b.body_id: b for b in frame.bodies}
            present_ids = [b.body_id for b in frame.bodies]
            st.last_present = present_ids
        # drain after this frame: always, or offline only when a window is due or a body leaves,
        # or (clean_on_poll) never: poll() drains, or the stream's next frame first
        if self._clean_on_poll:
            drain = False
            if st.undrained:
                self._drain(st, out)
            st.undrained = True
        else:
            drain = not self._batch_clean or self._due(st, present_ids)
            if drain and self._batch_clean:
                self._drain(st, out)  # first what a drain after every push would have left
        pend = PendingFrame(seq, t_ns, frame is None, present_ids)
        st.pending[g] = pend
        if not present_ids:
            pend.missing = 0
        # new bodies
        for bid in present_ids:
            if bid not in st.bodies:
                returning = bid in st.retired
                prior = st.retired.pop(bid, None)
                if returning:
                    self.counters["bodies_reidentified"] += 1
                body = Body(bid, g, self.cfg, self.skeleton, self._backlog, prior)
                body.live_path = LivePath(self.n_joints, self.bones, self.cfg.rate_hz, self.cfg.live,
                                          camera_space=self.skeleton.name in CAMERA_SPACE_SKELETONS,
                                          mirror_bones=self._mirror_bones)
                lengths = self._fixed_lengths if self._fixed_lengths is not None else prior
                body.live_path.set_bone_lengths(lengths)
                if self.cfg.live_carry and self.cfg.live_output:
                    body.live_carry = WindowCarry(body.live_path.levels, self.n_joints, self.cfg.rate_hz)
                ordinal = self.counters["bodies_seen"] if self._body_ordinal is None else self._body_ordinal()
                body.phase = hop_phase(ordinal, self.hop)
                st.bodies[bid] = body
                self.counters["bodies_seen"] += 1
        live_bodies: list[BodyFrame] = []
        t_s = t_ns * 1e-9
        for bid, body in list(st.bodies.items()):
            n = body.count
            k = n % body.cap
            body.reuse_rows(k)
            if bid in present_ids:
                t0 = time.perf_counter()
                bf = inputs.get(bid)
                if bf is not None:
                    body.ring.push(np.asarray(bf.positions, dtype=np.float64), np.asarray(bf.confidence, dtype=np.float64), t_ns)
                else:
                    body.ring.push_missing(t_ns)
                pos, conf, valid = body.ring.frame(n)
                if self.cfg.live_output:
                    if body.absent > 3:
                        body.live_path.reset()
                        if body.live_carry is not None:
                            body.live_carry.reset()
                    y, rec = body.live_path.step(pos, valid, t_s)
                    if body.live_carry is not None:
                        y, rec = body.live_carry.apply(pos, valid, y, rec, n)
                    body.store_present(k, n, pos, conf, valid, y, rec)
                else:  # offline: no live path (its output would be discarded)
                    body.store_present(k, n, pos, conf, valid, np.nan, True)
                if self.cfg.live_output:
                    if self._live_bias is None:
                        shown = y.copy()
                    else:  # the stored live value (clean's fallback) stays as it was
                        shown, body.live_bias_last = self._live_bias.step(y, body.live_bias_last)
                    live_bodies.append(
                        BodyFrame(bid, shown, output_confidence(y, conf if bf is not None else None, rec), rec.copy())
                    )
                    self.live_hist.observe(time.perf_counter() - t0)
            else:
                body.ring.push_missing(t_ns)
                body.live[k] = np.nan
                body.live_rec[k] = True
                body.conf[k] = 0.0
                body.raw[k] = np.nan
                body.valid[k] = False
                body.present[k] = False
                body.absent += 1
            body.count += 1
            if body.count == body.next_end:
                # extra windows while the body's first window fills (blending.next_window_end); not while
                # degraded, nor while other windows wait for the solver (they are extras: see _startup_hop)
                startup = self._startup_hop()
                body.next_end = next_window_end(body.count, self.cfg.window, self.hop, startup,
                                                self.cfg.lookahead + 1 - body.phase)
                self._schedule(st, body, body.count, hop_after=body.next_end - body.count)
        # live output in input body order
        if self.cfg.live_output:
            live_frame = SkeletonFrame(
                st.stream_id, seq, t_ns, self.skeleton.name, live_bodies, filled=frame is None
            )
            out.append(("live", live_frame))
            self.counters["live_out"] += 1
        # timeouts
        for body in list(st.bodies.values()):
            if body.absent > self._timeout:
                self.counters["bodies_timed_out"] += 1
                self._begin_end(st, body)
        if drain:
            self._drain(st, out)

    def _due(self, st: StreamState, present_ids: list[int]) -> bool:
        """Whether the next frame of ``st`` (bodies ``present_ids``) completes a body's window,
        times a body out, or finds a body leaving: work a drain must see the state before."""
        if st.ending:
            return True
        for bid, body in st.bodies.items():
            if body.count + 1 == body.next_end:
                return True
            if bid not in present_ids and body.absent + 1 > self._timeout:
                return True
        return False

    def _robust_lengths(self, body: Body) -> np.ndarray | None:
        """``(B,)`` bone lengths (m) for the solver and the live projection, now."""
        return self._length_sources(body).resolve()

    def _length_sources(self, body: Body) -> LengthSources:
        """What the body's bone lengths come from (:func:`~streamfix.streaming.bone_lengths.length_sources`)."""
        return length_sources(body, self.bones, self._mirror_bones, self.cfg.rate_hz, self._fixed_lengths,
                              MAX_BONE_M if self.skeleton.name in CAMERA_SPACE_SKELETONS else None)

    # ------------------------------------------------------------------ windows
    def _schedule(self, st: StreamState, body: Body, end: int, final: bool = False,
                  hop_after: int | None = None) -> None:
        """Create the job for the window ending at ``end`` and solve/submit it; ``hop_after``:
        frames to the body's next window (None: the hop)."""
        W = self.cfg.window
        win = body.ring.window(W, end)
        if win.end - win.start < 1:
            return
        self.counters["windows_scheduled"] += 1
        job = Job(
            body, win.start, win.end, win.positions.copy(), win.confidence.copy(),
            self._length_sources(body), self.degradation.iterations(), final,
        )
        job.hop_after = self.hop if hop_after is None else hop_after
        job.hop_before = end - body.last_scheduled_end if body.last_scheduled_end > 0 else job.hop_after
        if self._history:
            # the clean output of the frames before the window (row -1 = frame start - 1)
            h = body.history()
            job.history = h[: max(0, len(h) - max(0, body.hist_n - win.start))]
        body.jobs.append(job)
        body.last_scheduled_end = end
        if not win.valid.any():
            job.status = "skipped"
            self.counters["windows_skipped"] += 1
            return
        if not self.threaded:
            self._run_job(job)
            return
        if self.degradation.check(self._inflight, self._windows_due(), self._active_bodies(), self._done_total):
            self.counters["degrade_events"] += 1
        if self._inflight >= self.cfg.max_pending_windows * self._windows_due() and not final:
            job.status = "skipped"
            self.counters["windows_skipped"] += 1
            return
        with self._lock:
            self._inflight += 1
        self._deferred.append(job)  # submitted by the next poll(), push() or flush()

    def _submit_deferred(self) -> None:
        """Hand the windows scheduled since the last call to the solver pool, in order."""
        if self._deferred:
            jobs, self._deferred = self._deferred, []
            for job in jobs:
                self._pool.submit(lambda job=job: self._solve_queued(job))

    def _startup_hop(self) -> int:
        """The hop (frames) to a starting body's next window: ``cfg.startup_hop`` while the solver
        keeps up, else the hop (no extra window).

        Bodies that appear together all start together: their extra windows multiply the solver's
        work for their first ``window`` frames, and with many bodies serve's clean output fell behind
        for seconds (bench_service). Extras only refine a new body's first seconds, so under the overload
        policy (``cfg.degrade``, threaded) they are solved only when no window of any engine waits
        in the shared pool's queue. Synchronous engines (files) and ``degrade=False``: always.
        """
        if self.level > 0:
            return self.hop
        if self.cfg.degrade and self._pool is not None and self._pool.queued > 0:
            return self.hop
        return self.cfg.startup_hop

    def _active_bodies(self) -> int:
        """Bodies currently tracked over all streams (>= 1): each owes one window per hop."""
        return max(1, sum(len(st.bodies) for st in self.streams.values()))

    def _windows_due(self) -> float:
        """Windows the tracked bodies owe per hop, over all streams (>= 1): one per body, and
        ``hop / startup_hop`` for a body whose first window is still filling (at level 0;
        those windows are short, so the time a body's windows may take per hop is the same)."""
        startup = self.hop / self.cfg.startup_hop if self.level == 0 else 1.0
        W = self.cfg.window
        bodies = (b for st in self.streams.values() for b in st.bodies.values())
        return max(1.0, float(sum(startup if b.count < W else 1.0 for b in bodies)))

    def _run_job(self, job: Job) -> None:
        """Solve one window (a pool thread in threaded mode); sets the job's result."""
        config = with_max_iterations(self._solver_config, job.iterations, self.solver)
        bridged = solve_job(job, self.solver, self.bones, self.cfg.rate_hz, self.cfg.window, config,
                            pass_history=self._history, skeleton=self.skeleton if self._pass_skeleton else None)
        if bridged:
            with self._lock:
                for src, k in bridged.items():
                    key = "bridge_errors" if src == "errors" else f"joints_bridged_{src}"
                    self.counters[key] = self.counters.get(key, 0) + int(k)

    def _solve_queued(self, job: Job) -> None:
        """A queued window, in a thread of the shared pool (:mod:`~streamfix.streaming.solver_pool`):
        solve it unless it was abandoned or the engine closed; a failed solve is recorded on
        the job, never raised (only an ``on_window_done`` listener's error reaches the pool)."""
        try:
            if job.status == "pending" and not self._closed:
                self._run_job(job)
        except BaseException as exc:  # never leave a job pending: its frames would wait
            job.error = f"{type(exc).__name__}: {exc}"
            job.status = "done"
        finally:
            with self._cond:
                self._inflight -= 1
                self._done_total += 1
                self._cond.notify_all()
            if self.on_window_done is not None:
                self.on_window_done()  # a listener that raises is logged by the pool, which goes on

    # ------------------------------------------------------------------ results
    def _drain(self, st: StreamState, out: list) -> None:
        """Blend finished windows, finalise frames, retire finished bodies, emit clean frames."""
        st.undrained = False
        limit = self.cfg.lookahead + 1 + self._backlog
        for body in list(st.bodies.values()) + list(st.ending):
            if self.threaded:
                # a frame waiting too long beyond its lookahead: abandon the stalled window
                # (measured in stream frames, so a body that has left cannot hold the stream)
                while body.jobs and body.jobs[0].status == "pending" and st.g - (body.g0 + body.final_upto) >= limit:
                    body.jobs[0].status = "abandoned"
                    self.counters["windows_abandoned"] += 1
                    self._process_jobs(st, body)
            self._process_jobs(st, body)
            self._finalise(st, body)
            if body.ending and not body.jobs and body.final_upto >= body.count:
                self._retire(st, body)
        self._emit(st, out)

    def _process_jobs(self, st: StreamState, body: Body) -> None:
        """Blend finished windows at the head of the body's queue (in order)."""
        while body.jobs and body.jobs[0].status != "pending":
            job = body.jobs.popleft()
            prev_end = body.last_processed_end
            body.last_processed_end = max(body.last_processed_end, job.end)
            if job.status == "done":
                self.degradation.observe(job.solve_s, self._active_bodies())
                self.solve_hist.observe(job.solve_s)
                if job.error is not None:
                    self.counters["solver_errors"] += 1
                    if self._first_solver_error is None:
                        self._first_solver_error = job.error
                    continue
                self.counters["windows_solved"] += 1
                self.counters["solver_iterations"] += job.n_iter
                self._last_iterations = job.n_iter
                if not job.converged:
                    self.counters["solver_not_converged"] += 1
                blend_window(body, job, prev_end, self.cfg, self._output_taps, self._fill_taps)
                if self.cfg.live_output and job.noise_reported:  # the live filter smooths as much as it found noise
                    body.live_path.set_noise_share(job.noise_share)
                if self.cfg.live_anchor and self.cfg.live_output and job.end == body.count and job.result_pos is not None:
                    body.live_path.anchor(job.result_pos[-3:])
                if body.live_carry is not None and job.result_pos is not None and body.count - job.end < self.hop:
                    # the window's newest frames: its verdict on now
                    rows = np.arange(max(job.start, job.end - body.live_carry.confirm_frames), job.end) % body.cap
                    n = len(rows)
                    judged = ~body.valid[rows]  # the sensor gave nothing, or a stage judged it wrong
                    if job.judged is not None:
                        judged = judged | job.judged[-n:]
                    body.live_carry.take(job.result_pos[-n:], body.raw[rows], body.valid[rows], judged, job.end - 1)

    def _finalise(self, st: StreamState, body: Body) -> None:
        """Move the body's frames whose clean value can no longer change to the stream
        (:mod:`~streamfix.streaming.finalise`: one array pass over the run)."""
        end = final_end(body, self.cfg.lookahead)
        if end <= body.final_upto:
            return
        recovered, fallback = finalise_frames(
            st, body, end, self.bones, self.cfg.hop, learn_lengths=self._learn_lengths,
            live_output=self.cfg.live_output, history=self._history, pose_bias=self._pose_bias,
            bias_alpha=self._bias_alpha,
        )
        self.counters["joints_recovered"] += recovered
        if fallback:
            self.counters["joints_live_fallback"] += fallback

    def _emit(self, st: StreamState, out: list) -> None:
        while True:
            pend = st.pending.get(st.emit_g)
            if pend is None or pend.missing > 0:
                return
            del st.pending[st.emit_g]
            st.emit_g += 1
            bodies = [pend.slots[bid] for bid in pend.order if bid in pend.slots]
            out.append(
                ("clean", SkeletonFrame(st.stream_id, pend.seq, pend.time_ns, self.skeleton.name, bodies, filled=pend.filled))
            )
            self.counters["clean_out"] += 1

    # ------------------------------------------------------------------ lifecycle
    def _begin_end(self, st: StreamState, body: Body) -> None:
        """Body leaves (timeout, flush, discontinuity): solve a last window up to its newest
        present frame; the body stops taking frames (a returning id starts a new body)."""
        if body.ending:
            return
        body.ending = True
        if st.bodies.get(body.body_id) is body:
            del st.bodies[body.body_id]
        st.ending.append(body)
        end = body.last_present + 1
        if end > body.last_scheduled_end and end > body.final_upto:
            self._schedule(st, body, end, final=True)

    def _retire(self, st: StreamState, body: Body) -> None:
        if body in st.ending:
            st.ending.remove(body)
        st.retired[body.body_id] = self._robust_lengths(body)
        while len(st.retired) > 64:
            st.retired.pop(next(iter(st.retired)))

    def _end_stream_bodies(self, st: StreamState, out: list) -> None:
        """A discontinuity: every body leaves; its frames are emitted when its last window is done."""
        for body in list(st.bodies.values()):
            self._begin_end(st, body)
        self._drain(st, out)


class ThreadedStreamEngine(StreamEngine):
    """:class:`StreamEngine` whose windows are solved in the shared solver pool (live service mode)."""

    def __init__(self, skeleton: Skeleton, config: EngineConfig | None = None, window_solver: WindowSolver | None = None,
                 *, body_ordinals: Callable[[], int] | None = None, clean_on_poll: bool = False) -> None:
        super().__init__(skeleton, config, window_solver, threaded=True, body_ordinals=body_ordinals,
                         clean_on_poll=clean_on_poll)
