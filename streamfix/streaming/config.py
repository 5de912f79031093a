"""Streaming engine settings: window, hop and lookahead (frames or seconds), the live path's
settings and the degradation, body-timeout and dropped-frame policies (see
:mod:`streamfix.streaming.engine` for what each does)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .blending import FILL_SMOOTH_S, HANDOVER_S, OUTPUT_SMOOTH_S, crossfade_frames, handover_frames
from .live import LiveConfig

__all__ = [
    "EngineConfig", "DEFAULT_WINDOW_S", "DEFAULT_LOOKAHEAD_S", "DEFAULT_HOP_S",
    "FILE_WINDOW_S", "FILE_HOP_S", "FILE_LOOKAHEAD_S", "FILE_HANDOVER_S", "SCHEDULES", "schedule_config",
]

DEFAULT_WINDOW_S = 2.0  # W: 60 frames at 30 Hz
DEFAULT_LOOKAHEAD_S = 0.5  # L: 15 frames at 30 Hz (the bound on clean latency)
DEFAULT_HOP_S = 1.0 / 3.0  # H: 10 frames at 30 Hz

# The schedule for files (EngineConfig.for_files): nobody waits for a frame of a file, so
# each frame takes its value from windows that hold it well inside, and long windows see
# more of the body's motion per solve (the robust fits, the low-rank model and the bone
# lengths have more frames to go on) while fewer solves cover each frame (W / H = 1.11
# instead of serve's 6; a take up to 20 s, an exercise repetition or a short capture, is
# one window). Two consecutive windows share K = L + 1 - H frames, the older window's
# newest and the newer window's oldest used ones (W - L - 1 frames into it); the
# crossfade (FILE_HANDOVER_S) lies at the older window's end of them, so where they hand
# over each window has at least 16 frames (0.5 s) beyond (with windows every W - 1 s the
# newer window had none and the hand-overs showed as a seam; 3 s windows every 2 s, whose
# K was 1 frame, showed one too). The length: 10 s windows every 8 s were chosen over 3,
# 6 and 8 s windows by bench_paired, bench_sensor and bench_accuracy; 20 s windows every
# 18 s score the same within each benchmark's take-to-take spread (better on some error
# kinds, worse on others, no systematic loss; the paired takes are one window either way)
# and cost less: fewer frames solved twice on long files, and a take of 10-20 s is one
# solve instead of three (issue 13's offline speed target; benchmarks/results/speed.json).
FILE_WINDOW_S = 20.0  # W: 600 frames at 30 Hz
FILE_HOP_S = 18.0  # H: 540 frames at 30 Hz
FILE_LOOKAHEAD_S = 19.0  # L: 570 frames at 30 Hz: a frame is 0.5-19 s from its windows' newest frame
FILE_HANDOVER_S = 0.5  # crossfade within the K = 31 frames (1 s) consecutive windows share


def _frames_from_seconds(rate_hz: float, window: int | None, lookahead: int | None, hop: int | None,
                         seconds: tuple[float, float, float]) -> tuple[int, int, int]:
    """(W, L, H) frames: those given, the others from ``seconds`` (window, lookahead, hop)
    at ``rate_hz``, a default lookahead at most ``W - 1`` and a default hop at most ``L + 1``."""
    def frames(s: float) -> int:
        return max(1, int(round(s * rate_hz)))

    W = frames(seconds[0]) if window is None else window
    L = min(frames(seconds[1]), W - 1) if lookahead is None else lookahead
    H = min(frames(seconds[2]), L + 1) if hop is None else hop
    return W, L, H


@dataclass(frozen=True)
class EngineConfig:
    """Streaming engine settings (frames, seconds, Hz).

    window W, hop H, lookahead L: frames, ``1 <= H <= L + 1 <= W``; the clean output's
    latency is ``L / rate_hz`` s plus compute. Left None, they follow the defaults in
    seconds (W 2 s, H 1/3 s, L 0.5 s) at ``rate_hz``: 60/10/15 frames at 30 Hz. rate_hz: nominal sensor rate (drop
    detection, filters). live: the live path's settings. max_iterations: solver
    iteration cap per window (None = the solver's default). solver_config: passed as
    ``config=`` to the window solver (None = its default). bone_lengths: fixed
    ``(B,)`` bone lengths in metres (None = estimated robustly per body); the window
    cleaner still leaves tracked bones their length play around them unless its config
    says ``projection_tolerance=0`` (``streamfix clean --skeleton-lengths`` does).
    degrade: allow degradation in threaded mode (and skip a starting body's extra windows
    while other windows wait for the solver). degraded_iterations: iterations at
    level 1 (None = half of max_iterations, or 10 if that is None). max_hop: hop at the
    deepest level (None = W // 2). max_pending_windows: windows queued per tracked body beyond which
    new windows are skipped. max_clean_delay_s: how long beyond the lookahead a frame may
    wait for a stalled window before it is abandoned (at most ``8 W`` frames).
    recover_after: healthy windows
    before recovering a level. body_timeout_s: grace period of an absent body.
    fill_drops: synthesise dropped frames. drop_gap_factor: a timestamp gap above this
    many frame periods is a drop. max_fill_s: longer gaps are discontinuities.
    threaded: solve windows in the shared solver pool (the service's mode). lookahead_s: the
    lookahead in seconds instead of frames (rounded at ``rate_hz``; wins if given).
    live_anchor: re-anchor the live path's 'predict' gate on each solved window's newest
    frames when the solution is current (the live output is "corrected by the last
    solved window"; it stays causal). Off by default: the window's newest frames have no
    lookahead and measured worse than the Theil-Sen gate alone.
    live_carry: the live topic takes a solved window's pose of the joints it found broken on
    its newest frames (frozen, swapped, lost, jumped) and carries it, from their parents, until
    a newer window or the sensor says otherwise (:mod:`streamfix.streaming.live_carry`); False:
    the live topic is the live path's own output alone.
    live_output: run the live path and emit ``live`` frames. False (offline cleaning,
    which keeps only ``clean``) skips the live path's per-frame work; ``clean`` is
    unchanged except for a joint that no solved window gives a value (a window that
    failed or was skipped), which is then NaN and recovered instead of the live value;
    ``metrics()['joints_live_fallback']`` counts such joint-frames (the offline runner
    re-runs with the live path when it is not 0).
    handover_s: the crossfade at a window hand-over, seconds (at most the frames two
    consecutive windows share; see :func:`streamfix.streaming.blending.handover_weights`).
    startup_hop: the hop (frames) while a body's first ``window`` frames arrive
    (:func:`streamfix.streaming.blending.next_window_end`); None = ``max(1, hop // 2)``, at most
    ``hop`` (= no extra windows: the file schedule, whose long lookahead gains nothing from them).
    output_smooth_s: half-width (s) of the binomial whose twicing smooths the blended clean
    output where windows found sensor noise (``h`` frames at ``rate_hz`` give a ``4 h + 1``
    tap kernel, :func:`streamfix.core.filters.twiced_binomial_taps`; 0 = none): the
    frame-to-frame jitter that window estimates and their hand-overs leave.
    fill_smooth_s: the same for joint-frames that are the model's fill rather than a
    measurement (:data:`streamfix.streaming.blending.FILL_DISTANCE_M`); at least
    ``output_smooth_s`` (equal = no wider smoothing; none when ``output_smooth_s`` is 0).
    sensor_bias: the learned pose-dependent sensor bias removed from the clean and live
    outputs (:mod:`streamfix.core.pose_bias`; live one frame at a time,
    :mod:`streamfix.core.pose_bias_live`): ``"auto"`` (the model shipped for the stream's
    skeleton, if any), None / ``"off"``, a model file's path or a model
    (:func:`streamfix.sensor_bias.resolve_sensor_bias`). Applied to what is emitted only:
    the bone lengths, history and windows the engine keeps are the uncorrected ones.
    """

    window: int | None = None
    hop: int | None = None
    lookahead: int | None = None
    rate_hz: float = 30.0
    live: LiveConfig = field(default_factory=LiveConfig)
    max_iterations: int | None = None
    solver_config: Any = None
    bone_lengths: tuple[float, ...] | None = None
    degrade: bool = True
    degraded_iterations: int | None = None
    max_hop: int | None = None
    max_pending_windows: int = 4
    max_clean_delay_s: float = 2.0
    recover_after: int = 8
    body_timeout_s: float = 1.0
    fill_drops: bool = True
    drop_gap_factor: float = 1.5
    max_fill_s: float = 1.0
    threaded: bool = False
    lookahead_s: float | None = None
    live_anchor: bool = False
    live_output: bool = True
    live_carry: bool = True
    handover_s: float = HANDOVER_S
    startup_hop: int | None = None
    output_smooth_s: float = OUTPUT_SMOOTH_S
    fill_smooth_s: float = FILL_SMOOTH_S
    sensor_bias: Any = field(default="auto", compare=False)

    @classmethod
    def for_files(cls, rate_hz: float = 30.0, **settings: Any) -> "EngineConfig":
        """The schedule ``streamfix clean`` uses for recordings: window ``FILE_WINDOW_S``,
        hop ``FILE_HOP_S``, lookahead ``FILE_LOOKAHEAD_S``, crossfade ``FILE_HANDOVER_S`` (``settings`` override
        any field). The same window solver as ``serve``'s; the clean topic's 0.5 s latency
        bound does not apply to a file."""
        rate = float(rate_hz)
        if not (np.isfinite(rate) and rate > 0):
            raise ValueError(f"rate_hz must be a positive number, got {rate_hz}")
        lookahead_s = settings.pop("lookahead_s", None)
        lookahead = settings.pop("lookahead", None) if lookahead_s is None else int(round(float(lookahead_s) * rate))
        window, lookahead, hop = _frames_from_seconds(
            rate, settings.pop("window", None), lookahead, settings.pop("hop", None),
            (FILE_WINDOW_S, FILE_LOOKAHEAD_S, FILE_HOP_S),
        )
        base: dict[str, Any] = {"window": window, "hop": hop, "lookahead": lookahead, "handover_s": FILE_HANDOVER_S,
                                "startup_hop": hop}
        base.update(settings)
        return cls(rate_hz=rate, **base)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz must be a positive number, got {self.rate_hz}")
        if self.lookahead_s is not None:  # seconds win over frames
            if not self.lookahead_s >= 0:
                raise ValueError(f"lookahead_s must be >= 0 s, got {self.lookahead_s}")
            object.__setattr__(self, "lookahead", int(round(self.lookahead_s * self.rate_hz)))
            object.__setattr__(self, "lookahead_s", None)
        # frame counts left unset follow the defaults in seconds at this rate
        W, L, H = _frames_from_seconds(self.rate_hz, self.window, self.lookahead, self.hop,
                                       (DEFAULT_WINDOW_S, DEFAULT_LOOKAHEAD_S, DEFAULT_HOP_S))
        object.__setattr__(self, "window", W)
        object.__setattr__(self, "lookahead", L)
        object.__setattr__(self, "hop", H)
        if not (np.isfinite(self.output_smooth_s) and self.output_smooth_s >= 0):
            raise ValueError(f"output_smooth_s must be >= 0 s, got {self.output_smooth_s}")
        if not (np.isfinite(self.fill_smooth_s) and self.fill_smooth_s >= self.output_smooth_s):
            raise ValueError(f"fill_smooth_s must be >= output_smooth_s ({self.output_smooth_s} s), "
                             f"got {self.fill_smooth_s}")
        if not (np.isfinite(self.handover_s) and self.handover_s > 0):
            raise ValueError(f"handover_s must be a positive number of seconds, got {self.handover_s}")
        W, H, L = self.window, self.hop, self.lookahead
        if W < 4:
            raise ValueError(f"window must be >= 4 frames (typically 50-300), got {W}")
        if not 0 <= L <= W - 1:
            raise ValueError(f"lookahead must be in 0..window-1 = 0..{W - 1} frames, got {L}")
        if not 1 <= H <= L + 1:
            raise ValueError(f"hop must be in 1..lookahead+1 = 1..{L + 1} frames, got {H}")
        if self.startup_hop is None:
            object.__setattr__(self, "startup_hop", max(1, H // 2))
        elif not 1 <= self.startup_hop <= H:
            raise ValueError(f"startup_hop must be in 1..hop = 1..{H} frames, got {self.startup_hop}")
        if self.max_hop is not None and not H <= self.max_hop <= W:
            raise ValueError(f"max_hop must be in hop..window = {H}..{W}, got {self.max_hop}")
        if self.max_iterations is not None and self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.drop_gap_factor <= 1.0:
            raise ValueError(f"drop_gap_factor must be > 1 frame period, got {self.drop_gap_factor}")
        if self.max_pending_windows < 1:
            raise ValueError(f"max_pending_windows must be >= 1, got {self.max_pending_windows}")

    @property
    def latency_s(self) -> float:
        """Fixed latency of the clean output before compute (the lookahead), seconds."""
        return self.lookahead / self.rate_hz

    def handover_frames(self, n_frames: int) -> np.ndarray:
        """``(T,)`` bool: the frames around this schedule's window hand-overs for one body
        (:func:`streamfix.streaming.blending.handover_frames`), where a seam would show."""
        return handover_frames(n_frames, self.lookahead, self.hop, crossfade_frames(self.handover_s, self.rate_hz),
                               self.window, self.startup_hop)

    @property
    def output_smooth_frames(self) -> int:
        """The binomial half-width of the clean output's smoothing in frames (0 = none)."""
        return int(round(self.output_smooth_s * self.rate_hz))

    @property
    def fill_smooth_frames(self) -> int:
        """The binomial half-width of the smoothing of fills in frames (see ``fill_smooth_s``)."""
        return int(round(self.fill_smooth_s * self.rate_hz))

    @property
    def hop_limit(self) -> int:
        return self.max_hop if self.max_hop is not None else max(self.hop, self.window // 2)


SCHEDULES = ("file", "serve")
"""Window schedules: ``file`` (:meth:`EngineConfig.for_files`, what ``streamfix clean``
runs) and ``serve`` (the :class:`EngineConfig` defaults, ``serve``'s ``clean`` topic)."""


def schedule_config(schedule: str, rate_hz: float, **settings: Any) -> EngineConfig:
    """The :class:`EngineConfig` of a named schedule (:data:`SCHEDULES`) at ``rate_hz``;
    ``settings`` (None values ignored) override its fields."""
    given = {k: v for k, v in settings.items() if v is not None}
    if schedule == "file":
        return EngineConfig.for_files(rate_hz, **given)
    if schedule == "serve":
        return EngineConfig(rate_hz=float(rate_hz), **given)
    raise ValueError(f"schedule must be one of {', '.join(SCHEDULES)}, got {schedule!r}")
