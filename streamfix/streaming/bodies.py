"""What the streaming engine keeps per tracked body and per stream: the raw ring, the
overlap-add accumulators, the bone-length memories and clean history of a body, a frame
waiting for its bodies' clean values, and the job one window becomes."""
from __future__ import annotations

from collections import deque

import numpy as np

from ..frames import BodyFrame
from ..skeletons import Skeleton
from .config import EngineConfig
from .live import LivePath
from .live_carry import WindowCarry
from .ring import RingBuffer

__all__ = [
    "Body", "Job", "PendingFrame", "StreamState", "hop_phase", "output_confidence",
    "BONE_HISTORY_S", "BONE_MEMORY_S", "BONE_SUPPORT_FRAMES", "BONE_SUPPORT_TOL_M", "BONE_OWN_SUPPORT_S",
    "BONE_PEAK_SHARE", "GUESSED_SHARE_POOLED", "HISTORY_S", "RECOVERED_CONFIDENCE",
]

BONE_HISTORY_S = 3.0  # clean output needed before its bone lengths replace per-window estimates
BONE_MEMORY_S = 10.0  # clean output the bone-length median runs over
BONE_SUPPORT_FRAMES = 4  # raw samples that must agree with a bone's mode before it is trusted
BONE_SUPPORT_TOL_M = 0.005  # ... to within this (m)
BONE_OWN_SUPPORT_S = 1.0  # tracked samples a bone needs to keep its own length (else inferred ones, the mirror's)
BONE_PEAK_SHARE = 0.1  # share of a bone's raw samples that must lie within BONE_SUPPORT_TOL_M of its mode
GUESSED_SHARE_POOLED = (0.01, 0.05)  # share of a bone's samples with an inferred end: from the first, pooling
# with its mirror begins; from the second, the pair shares one length (symmetric_lengths). Full at 5 %:
# with (0.02, 0.1) a hand the sensor guessed for a few percent of a short take kept most of the
# hands' difference, and ended far off its mirror (bench_accuracy's inferred-limb bar)
HISTORY_S = 10.0
"""Seconds of a body's clean output (observed samples; recovered ones NaN) kept for
solvers with ``wants_history`` (PCA gap filling trains on it)."""
RECOVERED_CONFIDENCE = 0.5
"""Confidence the engine gives a joint it recovered (protocol/SPEC.md: "its confidence is
the service's estimate"): the sensor's own value for a guessed joint (inferred)."""


def output_confidence(pos: np.ndarray, conf_in: np.ndarray | None, recovered: np.ndarray) -> np.ndarray:
    """Per-joint output confidence: the sensor's for observed joints,
    :data:`RECOVERED_CONFIDENCE` for recovered ones, 0 where there is no position."""
    finite = np.isfinite(pos).all(axis=1)
    base = np.zeros(len(pos)) if conf_in is None else np.asarray(conf_in, dtype=np.float64)
    out = np.where(recovered, RECOVERED_CONFIDENCE, base)
    return out if finite.all() else np.where(finite, out, 0.0)


class Job:
    """One window to solve for one body: frames [start, end) of its timeline."""

    __slots__ = (
        "body", "start", "end", "positions", "confidence", "bone_lengths", "iterations",
        "status", "result_pos", "result_rec", "solve_s", "n_iter", "converged", "error", "final", "history",
        "hop_before", "hop_after", "noise_share", "noise_reported", "released", "judged",
    )

    def __init__(self, body: "Body", start: int, end: int, positions, confidence, bone_lengths, iterations, final=False):
        self.body = body
        self.start, self.end = start, end
        self.positions, self.confidence = positions, confidence
        self.bone_lengths = bone_lengths
        self.iterations = iterations
        self.status = "pending"  # pending -> done | skipped | abandoned
        self.result_pos = self.result_rec = None
        self.solve_s = 0.0
        self.n_iter = 0
        self.converged = False
        self.error: str | None = None
        self.final = final
        self.history: np.ndarray | None = None
        self.noise_share = 0.0  # how much of the window's output the engine smooths (solver's info)
        self.noise_reported = False  # the solver said so (a solver that does not leaves the live filter as it is)
        self.released: np.ndarray | None = None  # (T, J) samples the solver released as frozen (its info)
        self.judged: np.ndarray | None = None  # (T, J) samples its real-sensor stages judged wrong (its info)
        self.hop_before = self.hop_after = 0  # frames from the previous window's end / to the next one's (blend weights)


def hop_phase(ordinal: int, hop: int) -> int:
    """Frames (0 <= p < hop) by which the ``ordinal``-th body's windows are offset.

    Bodies that appear together would otherwise all schedule their windows on the same
    frame, and the worker solves them one after another: with 12 bodies the last
    waited 12 solves (clean latency far beyond the lookahead in bench_service). The
    golden-ratio sequence spreads any number of bodies evenly over the hop, rounded to
    the nearest frame: at serve's 10-frame hop the six bodies a Kinect tracks then get six
    phases (rounding down gave the sixth the first one's, so their windows queued
    together). The first body gets 0, so a single body's output is unchanged. Only the second window
    comes early (its hop is shorter), so every frame is still covered (H <= L + 1).
    A synchronous engine numbers its own bodies; threaded engines (``serve``, one per
    stream) number theirs together through the solver pool they share
    (:meth:`streamfix.streaming.solver_pool.SolverPool.next_body_ordinal`).
    """
    return int(((ordinal * 0.6180339887498949) % 1.0) * hop + 0.5) % hop


class Body:
    """Everything the engine keeps about one tracked body of one stream."""

    def __init__(self, body_id: int, g0: int, cfg: EngineConfig, skeleton: Skeleton, backlog: int, prior_lengths=None):
        J = skeleton.n_joints
        B = skeleton.n_bones
        self.body_id = body_id
        self.g0 = g0  # stream frame index of timeline frame 0
        self.ring = RingBuffer(cfg.window, J)
        cap = cfg.window + backlog + cfg.hop_limit + 2
        self.cap = cap
        # per-frame output accumulators, indexed by timeline frame % cap
        self.mean = np.zeros((cap, J, 3))
        self.den = np.zeros((cap, J))
        self.recw = np.zeros((cap, J))
        self.smooth = np.zeros((cap, J, 3))  # the blended mean smoothed over time (overlap_add.smooth_output)
        self.smooth_for = np.full(cap, -1, dtype=np.int64)  # the timeline frame each smooth row holds
        self.noise = np.zeros((cap, J))  # the windows' noise_share, blended like the positions
        # blended only from windows that knew more than older ones (overlap_add.blend_window)
        self.informed_only = np.zeros((cap, J), dtype=bool)
        self.live = np.full((cap, J, 3), np.nan)
        self.live_rec = np.zeros((cap, J), dtype=bool)
        self.conf = np.zeros((cap, J))
        self.raw = np.full((cap, J, 3), np.nan)  # the sensor's sample (NaN = none), for overlap_add.fill_mask
        self.valid = np.zeros((cap, J), dtype=bool)
        self.present = np.zeros(cap, dtype=bool)
        self.count = 0  # frames in the timeline
        self.final_upto = 0  # next frame to finalise
        self.next_end = cfg.lookahead + 1  # end of the next window to schedule
        self.phase = 0  # frames the window grid after the first window is shifted early by (spreads bodies)
        self.last_scheduled_end = 0
        self.last_processed_end = 0
        self.last_present = -1
        self.absent = 0  # consecutive absent frames
        self.jobs: deque[Job] = deque()
        self.ending = False
        # worker-owned warm-start state
        self.solver_state = None
        self.solver_state_end = -1
        # bone lengths sampled from the body's clean output (median -> clean_lengths)
        self.clean_bones = np.full((max(1, int(round(BONE_MEMORY_S * cfg.rate_hz))), B), np.nan)
        self.clean_bones_n = 0
        self.clean_pending: list[np.ndarray] = []  # clean frames not yet in clean_bones (< one hop)
        self.clean_lengths: np.ndarray | None = None
        # per-frame bone lengths of the raw input where both ends are tracked (ring, NaN = none)
        self.raw_bones = np.full((max(1, int(round(BONE_MEMORY_S * cfg.rate_hz))), B), np.nan)
        self.raw_bones_seen = np.full_like(self.raw_bones, np.nan)  # the same, inferred samples too
        self.raw_bones_end = 0  # absolute frame index up to which raw_bones is filled
        self.prior_lengths = prior_lengths
        self.live_path: LivePath | None = None
        self.live_carry: WindowCarry | None = None  # EngineConfig.live_carry: the windows' verdict on live
        # the body's recent clean output for history-trained solvers (ring, oldest first on read)
        self.hist = np.full((max(1, int(round(HISTORY_S * cfg.rate_hz))), J, 3), np.nan)
        self.hist_n = 0
        self.bias_last: np.ndarray | None = None  # (J, 3) m: the sensor-bias shift of the last emitted frame
        self.live_bias_last: np.ndarray | None = None  # (J, 3) m: the same for the live topic

    def reuse_rows(self, rows) -> None:
        """Clear the output accumulators of timeline rows ``rows`` (an index or an array of
        them, frame % cap) for new frames; their old frames were finalised long ago."""
        for acc in (self.mean, self.den, self.recw, self.noise):
            acc[rows] = 0.0
        self.informed_only[rows] = False

    def store_present(self, rows, last: int, raw, conf, valid, live, live_rec) -> None:
        """Record present frames in timeline rows ``rows``: the sensor's samples as the
        ring stored them (``raw`` m, NaN where invalid; ``conf``; ``valid``) and the live
        path's output (``live`` m, ``live_rec``); ``last`` = the newest one's timeline frame."""
        self.live[rows] = live
        self.live_rec[rows] = live_rec
        self.conf[rows] = conf
        self.raw[rows] = raw
        self.valid[rows] = valid
        self.present[rows] = True
        self.absent = 0
        self.last_present = last

    def history(self) -> np.ndarray:
        """``(T_h, J, 3)`` copy of the kept clean history, oldest frame first."""
        n, cap = self.hist_n, len(self.hist)
        if n <= cap:
            return self.hist[:n].copy()
        k = n % cap
        return np.concatenate([self.hist[k:], self.hist[:k]])


class PendingFrame:
    """A stream frame awaiting the clean values of its bodies."""

    __slots__ = ("seq", "time_ns", "filled", "order", "slots", "missing")

    def __init__(self, seq: int, time_ns: int, filled: bool, order: list[int]):
        self.seq, self.time_ns, self.filled = seq, time_ns, filled
        self.order = order
        self.slots: dict[int, BodyFrame] = {}
        self.missing = len(order)


class StreamState:
    def __init__(self, stream_id: str, seq0: int):
        self.stream_id = stream_id
        self.seq0 = seq0
        self.g = -1  # index of the newest stream frame
        self.last_in_seq: int | None = None
        self.last_time_ns: int | None = None
        self.bodies: dict[int, Body] = {}  # active bodies
        self.ending: list[Body] = []  # bodies that left, finishing their last window
        self.last_present: list[int] = []  # body ids of the newest real frame
        self.undrained = False  # a frame pushed since the last drain (engine clean_on_poll)
        self.pending: dict[int, PendingFrame] = {}
        self.emit_g = 0
        self.retired: dict[int, np.ndarray | None] = {}
