"""The default window solver: long gaps bridged first (PCA on the body's clean history,
the learned prior for Kinect v2), then ``streamfix.core.pipeline.clean_window``.

Why
---
``clean_window`` (robust fit + low-rank ALM solver) bridges short gaps from the other
joints and the neighbouring frames, but a joint missing for most of a window has
almost nothing to anchor it: the low-rank solution of a seated person's missing leg
lands far from the body, and a joint missing for the *whole* window makes the solver
fail outright. Issue 4 (item 4) fills such joints from the prior's latent fit D(z*);
issue 5 (items 2-3) from PCA (Li et al. 2020, Eq. 4 / Eq. 16) trained on the body's own
recent clean history, "so that it works with no prepared data at all".

What counts as long (frames; ``T`` = window length)
----------------------------------------------------
* a joint whose run of consecutive missing frames *within the window* is
  ``>= long_gap_frames(T, rate) = max(LONG_GAP_MIN, ceil(min(T, GAP_SCALE_MAX_S * rate) * LONG_GAP_FRACTION))``
  frames (1/3 of the window, or of 2 s for longer windows: 20 frames = 0.67 s at the default
  W = 60 / 30 Hz, on either schedule). A joint with no observation in the whole window is always long;
* a blackout: a run of ``>= BLACKOUT_MIN_FRAMES`` (3) consecutive frames in which
  fewer than 3 joints are observed (nothing in the frame ties the joints to each
  other; measured: the solver alone leaves such frames at the linear interpolation).

Where the fill comes from (first that applies, per sample)
----------------------------------------------------------
0. ``time``: a blackout closed on both sides (the clean history counts as the near side),
   on a skeleton the prior does not know: each joint's cubic spline through the history and
   the window (:func:`closed_blackout_mask`); on a marker set (no bones) each marker's spline
   in the frame of its most rigid neighbours
   (:func:`streamfix.core.corotating.corotating_blackouts`);
1. ``pca``: :class:`streamfix.core.pca_fill.PcaGapFiller` trained on the body's
   clean history (observed samples only; recovered ones are NaN), when the history
   has ``>= MIN_HISTORY_S`` (3 s) of frames where every joint to fill was observed;
2. ``prior``: :func:`streamfix.prior.init.fill_long_gaps` (D(z*) shifted to meet the
   observed samples at both ends) when the prior maps the skeleton's layout, on the newest
   frames only: one prior window (the solver's window and the few history frames before it),
   one latent fit per window solve, which keeps the prior within its latency budget.
   While the body travels (net speed ``>= TRAVEL_SPEED_MPS``, the excursion limit's rule
   below) the prior comes before PCA (``PRIOR_FIRST_WHILE_TRAVELLING``): a walking limb swings
   with the gait of the whole body, which the prior learnt from an hour of motion, while PCA's
   local templates predict a lost arm from a few trunk joints trained on seconds of history
   and, on a walking CMU take in ``serve``, stepped off the arm's last sample at the gap's
   first frame (``tests/test_prior_bridge.py`` holds the two fills of that arm against each
   other). In place (seated, exercising, gesturing) PCA on the person's own history stays
   first: with the excursion limit it keeps a still limb near its pose, where the unlimited
   prior wanders (``tests/test_integration_streaming_gaps.py``, a seated leg);
3. ``hold``: a joint missing for the whole window with neither source holds its last
   value from the history (counted, so it is never silent); with no history at all it
   is left missing and the window fails (the engine counts a solver error and uses the
   live values).

Continuity and excursion limit (not in the papers)
-------------------------------------------------
A gap still *open* at the window's end (no far end for the solver) is bridged once it
is ``open_gap_frames(T, rate)`` (W/6, at most 0.5 s) long: left to the low-rank fit, the
first frames of a limb gap were extrapolated far astray. A fill (every PCA fill, ``EXCURSION_SOURCES``,
and the prior's fills of the arms, ``PRIOR_LIMITED_LIMBS``) is then kept within
``EXCURSION_GAIN`` (0.35) times the joint's own range of motion over the 1 s before the
gap (RMS distance from its last observed sample) of the continuity baseline: hold from
the last observed sample (history included) while the far end is not in the window,
linear once it is (:func:`streamfix.core.excursion.limit_excursion`, relative to the
limb's anchor joint, so a walking body carries a held limb along). Why: with a
whole limb missing, PCA on seconds of history guesses its pose from coincidental
correlations with the rest of the body (the seated ankle's partners include the left
hand, resting on the knee), and an arm moves on its own, which nothing else in the body
tells the prior (a gesturing Kinect arm). Except while the body travels
(:data:`TRAVEL_SPEED_MPS`), for every source: a walking body's limbs swing with its gait,
which the rest of the body does tell the prior and PCA (whose history is the same gait),
and a limb held near its last pose while the body walks on loses the swing. The frozen
limb a sensor reports is exactly that held pose, so with the limit on, a frozen limb
released with no far end in the window (``serve``'s 0.5 s lookahead) was filled back onto
the frozen guess (on the sensor protocol's walking takes, frozen and dropped limbs were
filled closer to the truth with the fills free there; no window of the paired or
real-Kinect recordings, whose people exercise, gesture or sit in place, travels that
fast). The prior's fills of the legs and trunk are not limited: their motion is what it
learnt from an hour of real motion, and held near the last sample they lag a walking body
(``tests/test_prior_bridge.py`` holds a walking leg to this; the sensor protocol's dropouts
and a streamed occlusion protocol improved with it).
The gain trades the two failure modes: larger lets a moving limb keep its motion
through the gap, smaller keeps a still limb from wandering; the real-Kinect gap cases in
``tests/test_integration_streaming_gaps.py`` (a seated leg missing 3 s, a still arm, a
waving arm) hold the fill against hold, linear interpolation and low rank alone.

The filled samples enter ``clean_window`` as observations with confidence
:data:`FILL_CONFIDENCE` (so the robust fit and the bone projection may still move them,
more than inferred joints) and are flagged ``recovered`` in the result. A window with
no long gap goes to ``clean_window`` untouched (same result bit for bit, no extra cost
beyond the run-length test). Skeletons without a prior and without history (C3D
markers, BVH at the start of a stream) behave exactly as with ``clean_window`` alone.

Frozen inferred limbs released (``release_frozen``, on by default)
-------------------------------------------------------------------
An inferred limb joint (below a limb's root, on a bone of 15 cm or more: elbows, wrists,
knees, ankles) whose position relative to its parent follows a straight line for half a
second or more while its left/right twin bends is the sensor's frozen or drifting guess
(:mod:`streamfix.core.frozen`); the hands and feet below it go with it. Within 1-2 s of
a tracked sample of the same joint (``streamfix.core.inferred.TRACKED_NEAR_S``) these
samples become missing before anything else runs: the long-gap bridge and the window
pipeline fill them, and they are flagged ``recovered``. A release goes on to the end of the
rigid run in the windows after it, which may hold no tracked sample of the joint
(:mod:`streamfix.streaming.frozen_release`: the released samples ride along in the solver
state). The guess stays where no window released it near a tracked sample, and beside a
twin that does not clearly bend (a seated user's legs under a desk in
``seated_joints.csv``, one of them settling after a move). The hazard is a limb
the person really holds still while the other one moves, which looks the same: it is
replaced by the fill as well (the sensor protocol's ``flagged`` kind scores that cost;
``benchmarks/results/sensor.md`` has the figures).

The fills of released samples are not held by the excursion limit (``limit_released=False``).
Its baseline is the limb's last sample before the run, relative to the joint it hangs from,
which is the very pose the sensor froze in: with no far end in the window (``serve``'s 0.5 s
lookahead) the limit put the fill back onto the guess just rejected, and a frozen arm kept
most of its error in ``serve`` while ``clean`` (which sees the run's far end) replaced it.
The price is the hazard above: a still arm that was right, on a walking body, now swings
with the fill. The two cannot be told apart from the samples (the same input, two truths);
``tests/test_frozen_limbs.py`` measures both on one walking take, and the sensor protocol's
``freeze`` and ``mix`` kinds the gain.

Dislocated hands and feet released (``release_dislocated``, on by default)
-------------------------------------------------------------------------
A hand, hand tip, thumb or foot whose bone to its parent is off the body's length by
half or more (and 3 cm or more) for a third of a second, while the parent sits where its
own bone allows, is a sensor failure however it is flagged (a hand laid on the wrist).
After foot support (whose planted legs have their lengths), those samples are put back on
their parent from the joint's offset to it around the run, at the body's bone length, and
enter the window pipeline as low-confidence observations (``fill_confidence``), flagged
``recovered`` (:mod:`streamfix.core.dislocated`). Made missing instead, they sent the window
to the low-rank solver and the long-gap bridge: much of the engine's time on the Kinect v2
recordings, for practically the same KERAAL score. Nothing is judged before the engine has the
body's lengths. ``tests/test_dislocated.py`` measures it on the KERAAL take.

Joints read at the wrong depth put back on their ray (``repair_depth``, on by default)
----------------------------------------------------------------------------------
A joint a depth sensor read the depth behind it for (a thin limb on the body's silhouette:
the wall's depth, metres back along the joint's own camera ray) has a stretched bone and
sits far along its ray from where its good samples around put it. Before anything else looks
at lengths (foot support, the dislocated ends, the jumps), it is moved back along the ray to
its bone's length and enters the window pipeline as a low-confidence observation
(``fill_confidence``), flagged ``recovered`` (:mod:`streamfix.core.ray_depth`). Only for
:data:`streamfix.skeletons.CAMERA_SPACE_SKELETONS` (a room's coordinates have no sensor at the
origin), and not before the engine has the body's lengths. ``benchmarks/results/sensor.md``
(``depth``) has the figures; the live path repairs the same way, frame by frame.

Limbs that jumped as one piece released (``release_jumps``, on by default)
-------------------------------------------------------------------------
A forearm with its hand, or a shin with its foot, that the sensor moved by a decimetre or
more for 0.1-0.4 s and put back keeps its own bones, so the window's robust fit followed
it. One bone off its length abruptly for such a run, while the bones below its distal joint
and the other bones at its proximal joint keep theirs, says the distal side jumped
(:mod:`streamfix.core.limb_jumps`): those samples become missing, flagged ``recovered``,
and the window pipeline fills them in time (closed gaps up to ``PipelineConfig.time_gap_s``
are each joint's cubic spline). ``benchmarks/results/sensor.md`` (``jump``) has the figures.

Inferred limbs checked against the prior (``verify_inferred``, off by default)
-----------------------------------------------------------------------------
A sensor that loses a limb keeps reporting it, flagged inferred: frozen in its last pose
or drifting. With ``verify_inferred=True``, long runs of inferred samples near a tracked
sample of the same joint are compared with the prior's fill for them (made as if they
were missing, with a looser excursion limit) and give way to it where the two part
(:mod:`streamfix.core.inferred`). On the sensor protocol's frozen limbs and its mix
this lowers the error (``tests/test_inferred_limbs.py``, ``benchmarks/bench_sensor.py``
``freeze``), but an inferred limb that is *right* is then moved toward a fill whose error
on a swinging arm exceeds the check's threshold (the bench's ``flagged`` kind scores
that hazard). It stays off: a walking subject's right arm, flagged inferred, is moved by
several centimetres where unchecked it is within millimetres, and a threshold high
enough to leave it alone no longer frees a frozen arm (measured on CMU 131_01's walking
arm, the body of ``tests/test_inferred_limbs.py``, when this default was set).

The engine passes ``history`` (the body's recent clean output, ``(T_h, J, 3)``, NaN
where it was recovered) to solvers whose ``wants_history`` attribute is True.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..core.excursion import (EXCURSION_GAIN, EXCURSION_HORIZON_S, anchor_reference, limit_excursion,
                              parents_from_bones, travel_speed)
from ..core.interpolate import missing_run_lengths
from ..core.isometry import seen_bone_lengths
from ..core.points import finite_points
from ..limbs import mirror_bones
from ..skeletons import CAMERA_SPACE_SKELETONS, Skeleton
from .frozen_release import ReleaseState, frozen_release, limb_layout, split_state
from .solver_api import JUDGED_KEY, RELEASED_KEY, WindowOutput

__all__ = [
    "BridgingWindowSolver",
    "long_gap_frames",
    "missing_run_lengths",
    "long_missing_mask",
    "FILL_CONFIDENCE",
    "LONG_GAP_FRACTION",
    "LONG_GAP_MIN",
    "BLACKOUT_MIN_FRAMES",
    "MIN_HISTORY_S",
    "GAP_SCALE_MAX_S",
]

LONG_GAP_FRACTION = 1.0 / 3.0
"""A joint missing for this fraction of the window (or more) is bridged before the solver."""
OPEN_GAP_FRACTION = 1.0 / 6.0
"""... or this fraction when the run is still open at the window's end (no far end)."""
LONG_GAP_MIN = 4
"""... but never fewer than this many frames."""
GAP_SCALE_MAX_S = 2.0
"""The window length (s) those fractions refer to at most: a joint missing for a second is as
far beyond the low-rank fit in a 12 s window as in a 2 s one. With the fractions of the whole
window, a 12 s file window (``streamfix clean --window``) left 1-4 s limb gaps to the fit, which
placed a walking leg decimetres off (``tests/test_integration_streaming_gaps.py``). The file
schedule's windows (``streaming.config``) judge gaps as serve's 2 s window does: with 3 s, a
forearm or shin lost for 0.7-1 s was still the fit's, which put it further off than bridging
did (limb segments dropped on the CMU and Xia takes), and the sensor protocol's dropped
and frozen limbs came out worse (``benchmarks/results/sensor.md``)."""
BLACKOUT_MIN_FRAMES = 3
"""Runs of this many (or more) frames with fewer than 3 observed joints are bridged."""
BLACKOUT_JOINTS = 3
MIN_HISTORY_S = 3.0
"""Seconds of clean history (with the joints to fill observed) before PCA is trusted."""
FILL_CONFIDENCE = 0.25
"""Confidence of a bridged sample as the solver sees it (below 'inferred' 0.5)."""
EXCURSION_SOURCES = ("pca",)
"""Fill sources whose samples the excursion limit applies to (every joint; not while the body travels)."""
PRIOR_LIMITED_LIMBS = ("left_arm", "right_arm")
"""Limbs (``streamfix.canonical.CANONICAL_LIMBS``) whose prior fills the excursion limit still
applies to: an arm moves on its own, which the rest of the body cannot tell the prior..."""
TRAVEL_SPEED_MPS = 0.5
"""... unless the body travels at this net speed (m/s) or faster over the context and window
(:func:`streamfix.core.excursion.travel_speed`): then the limbs swing with the gait, which the
rest of the body does tell the prior and PCA (None = always limited)."""
VERIFY_HISTORY_S = 1.0
"""Seconds of clean history a body needs before the prior's fill may take the place of the
sensor's inferred samples it is checked against (``verify_inferred``): at a stream's start
the fill comes from the prior alone, which differs from window to window by more than the
hand-over crossfade hides."""
VERIFY_EXCURSION_GAIN: float | None = 1.0
"""Excursion limit of the fill the inferred samples are checked against: looser than the
gap fill's (its hold baseline is the limb's last tracked pose, which is what a frozen
limb keeps, so the usual limit pulls the fill onto the very guess being checked)."""
PRIOR_FIRST_WHILE_TRAVELLING = True
"""While the body travels (:data:`TRAVEL_SPEED_MPS`), the prior fills before PCA: see the module doc."""
PRIOR_INIT = "off"
PRIOR_METHOD = "latent"  # fill from D(z*) ("latent") or D(E(Y)) ("encode", cheaper)
"""Prior as the solver's start on the frames entering a window: 'off', 'bridged' (only
windows that had long gaps) or 'always' (every window with a missing sample, when the
skeleton has a prior). See :meth:`BridgingWindowSolver.prior_start`."""


def _gap_scale(n_frames: int, rate_hz: float) -> float:
    """The window length (frames) the gap fractions apply to: the window, at most ``GAP_SCALE_MAX_S``."""
    return min(float(n_frames), GAP_SCALE_MAX_S * float(rate_hz))


def long_gap_frames(n_frames: int, rate_hz: float) -> int:
    """Shortest missing run (frames) treated as long in a window of ``n_frames`` frames at ``rate_hz``."""
    return max(LONG_GAP_MIN, int(np.ceil(_gap_scale(n_frames, rate_hz) * LONG_GAP_FRACTION)))


def open_gap_frames(n_frames: int, rate_hz: float) -> int:
    """Shortest missing run (frames) still open at the window's end that is bridged."""
    return max(LONG_GAP_MIN, int(np.ceil(_gap_scale(n_frames, rate_hz) * OPEN_GAP_FRACTION)))


def long_missing_mask(observed: np.ndarray, rate_hz: float, n_frames: int | None = None) -> np.ndarray:
    """``(T, J)`` bool: missing samples the solver should not be left to bridge (see module doc)."""
    obs = np.asarray(observed, dtype=bool)
    T = obs.shape[0] if n_frames is None else n_frames
    run = missing_run_lengths(obs)
    long_ = run >= long_gap_frames(T, rate_hz)
    # a run still open at the window's end has no far end for the solver to bridge to:
    # extrapolating a limb from the low-rank fit goes far astray, so it is bridged
    # once it is OPEN_GAP_FRACTION of the window long
    seen_after = np.flipud(np.logical_or.accumulate(np.flipud(obs), axis=0))
    long_ |= ~seen_after & (run >= open_gap_frames(T, rate_hz))
    black = obs.sum(axis=1) < BLACKOUT_JOINTS
    if black.any():
        brun = missing_run_lengths(~black)
        long_ |= ((brun >= BLACKOUT_MIN_FRAMES)[:, None]) & ~obs
    return long_


def closed_blackout_mask(observed: np.ndarray) -> np.ndarray:
    """``(T, J)`` bool: missing samples whose joint's gap lies wholly in frames where no joint
    is observed (whole frames lost: the body dropped out of tracking, or frames dropped),
    with the joint observed on both sides.

    For a skeleton no learned prior knows (marker sets, BVH), the bridge fills these from
    time alone (each joint's cubic spline through the clean history and the window, source
    ``time``) before PCA: with nothing observed in those frames, PCA on the history left CMU
    marker blackouts (``eval --protocol blackout``) well above the spline's error. Where the
    prior knows the skeleton its fill stays: on UI-PRMD (Kinect v1) 0.2-0.5 s blackouts in
    mid-take, it ended closer to Vicon than the spline did. A blackout still open at the
    window's newest frames stays the models' (a spline could only hold the last value), as
    does a gap that runs on where other joints are seen.
    """
    obs = np.asarray(observed, dtype=bool)
    empty = ~obs.any(axis=1)
    if not empty.any():
        return np.zeros_like(obs)
    # a joint's gap is the blackout itself when the two runs are equally long (it contains it)
    same_run = missing_run_lengths(obs) == missing_run_lengths(~empty[:, None])
    seen_before = np.logical_or.accumulate(obs, axis=0)
    seen_after = np.flipud(np.logical_or.accumulate(np.flipud(obs), axis=0))
    return empty[:, None] & same_run & seen_before & seen_after


def _with_recovered(res: Any, mask: np.ndarray, bridged: dict | None = None) -> WindowOutput:
    """The solver's result with ``mask`` ``(T, J)`` added to its recovered joints (and
    ``bridged`` counts, when given, in place of its own)."""
    rec = getattr(res, "recovered", None)
    rec = mask.copy() if rec is None else (np.asarray(rec, dtype=bool) | mask)
    counts = bridged if bridged is not None else dict(getattr(res, "bridged", None) or {})
    return WindowOutput(
        np.asarray(res.positions), rec, getattr(res, "state", None), int(getattr(res, "iterations", 0) or 0),
        bool(getattr(res, "converged", True)), dict(getattr(res, "info", {}) or {}), counts,
    )


class BridgingWindowSolver:
    """Window solver: bridge long gaps (PCA on history, prior D(z*), hold), then ``base``.

    ``base``: the window solver to run afterwards (None = ``clean_window``).
    ``sources``: the fill sources tried, from ``("time", "pca", "prior")`` (``time`` first
    when given: closed whole-frame blackouts, :func:`closed_blackout_mask`).
    ``use_prior``: None = whenever a prior is shipped for the skeleton's joint count.
    ``travel_speed_mps``: the excursion-limited fills (PCA's, the prior's arms) are limited
    unless the body travels this fast (:data:`TRAVEL_SPEED_MPS`; None = always limited).
    ``history_s``: seconds of clean history the PCA trains on (the engine keeps
    :data:`HISTORY_S`). ``release_frozen`` / ``release_dislocated`` / ``release_jumps`` /
    ``verify_inferred`` / ``foot_support`` / ``undo_swaps`` / ``repair_depth``: the real-sensor stages in the
    module doc.
    ``limit_released``: the excursion limit also holds the fills of released frozen samples
    near the frozen pose (off: see "Frozen inferred limbs released" in the module doc).
    """

    wants_history = True
    wants_skeleton = True

    def __init__(
        self,
        base: Callable[..., Any] | None = None,
        *,
        sources: tuple[str, ...] = ("time", "pca", "prior"),
        use_prior: bool | None = None,
        min_history_s: float = MIN_HISTORY_S,
        fill_confidence: float = FILL_CONFIDENCE,
        prior_init: str = PRIOR_INIT,
        context_windows: float = 1.0,
        excursion_gain: float | None = EXCURSION_GAIN,
        foot_support: bool = True,
        undo_swaps: bool = True,
        prior_method: str = PRIOR_METHOD,
        excursion_sources: tuple[str, ...] = EXCURSION_SOURCES,
        prior_limited_limbs: tuple[str, ...] = PRIOR_LIMITED_LIMBS,
        travel_speed_mps: float | None = TRAVEL_SPEED_MPS,
        verify_inferred: bool = False,
        release_frozen: bool = True,
        release_dislocated: bool = True,
        release_jumps: bool = True,
        limit_released: bool = False,
        repair_depth: bool = True,
    ) -> None:
        if base is None:
            from ..core.pipeline import clean_window

            base = clean_window
        bad = [s for s in sources if s not in ("time", "pca", "prior")]
        if bad:
            raise ValueError(f"sources must be from ('time', 'pca', 'prior'), got {bad}")
        if prior_init not in ("off", "bridged", "always"):
            raise ValueError(f"prior_init must be 'off', 'bridged' or 'always', got {prior_init!r}")
        self.prior_init = prior_init
        self.foot_support = bool(foot_support)
        self.undo_swaps = bool(undo_swaps)
        self.verify_inferred = bool(verify_inferred)
        self.release_frozen = bool(release_frozen)
        self.release_dislocated = bool(release_dislocated)
        self.release_jumps = bool(release_jumps)
        self.repair_depth = bool(repair_depth)
        self.limit_released = bool(limit_released)
        self._limb_joints: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # limb joints, mirrors
        if prior_method not in ("latent", "encode"):
            raise ValueError(f"prior_method must be 'latent' or 'encode', got {prior_method!r}")
        self.prior_method = prior_method
        self.context_windows = float(context_windows)
        self.excursion_gain = None if excursion_gain is None else float(excursion_gain)
        self.excursion_sources = tuple(excursion_sources)
        self.prior_limited_limbs = tuple(prior_limited_limbs)
        self.travel_speed_mps = None if travel_speed_mps is None else float(travel_speed_mps)
        self.base = base
        self.sources = tuple(sources)
        self.use_prior = use_prior
        self.min_history_s = float(min_history_s)
        self.fill_confidence = float(fill_confidence)
        self._prior_ok: dict[int, bool] = {}

    # the engine reads the base solver's default config through this
    @property
    def base_solver(self) -> Callable[..., Any]:
        return self.base

    def prior_ok(self, n_joints: int, skeleton: str | None = None) -> bool:
        """Whether the prior maps this layout (by registry name when known; joint counts
        alone cannot tell a 32-marker C3D set from an Azure Kinect body)."""
        if self.use_prior is False:
            return False
        key = (n_joints, skeleton)
        if key not in self._prior_ok:
            try:
                from ..prior.init import prior_available

                self._prior_ok[key] = bool(prior_available(n_joints, skeleton=skeleton))
            except Exception:  # noqa: BLE001 - no prior runtime: simply no prior
                self._prior_ok[key] = False
        return self._prior_ok[key]

    def bridge(
        self, positions: np.ndarray, observed: np.ndarray, rate_hz: float, history: np.ndarray | None = None,
        skeleton: str | None = None, bones: np.ndarray | None = None, sources: tuple[str, ...] | None = None,
        excursion_gain: float | None | str = "default", unlimited: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        """Fill the long-missing samples of one window; returns (positions, bridged mask, counts by source).

        ``bones`` ``(B, 2)`` (parent, child): the excursion limit works relative to each
        limb's anchor when given, in world coordinates when not. ``sources``,
        ``excursion_gain``: in place of the solver's own. ``unlimited`` ``(T, J)`` bool:
        samples whose fills the excursion limit leaves alone (released frozen samples).
        """
        gain = self.excursion_gain if excursion_gain == "default" else excursion_gain
        x = np.asarray(positions, dtype=np.float64)
        obs = np.asarray(observed, dtype=bool) & finite_points(x)
        T, J = obs.shape
        counts: dict[str, int] = {}
        out = np.where(obs[..., None], x, np.nan)
        done = np.zeros_like(obs)
        if not obs.any():
            return out, done, counts
        # context: up to one window of the clean history just before the window, so a gap
        # that began earlier is seen with its observed start (history row -1 = frame -1)
        h = None if history is None or len(history) == 0 else np.asarray(history, dtype=np.float64)
        ctx = np.zeros((0, J, 3)) if h is None else h[-int(self.context_windows * T):]
        C = len(ctx)
        ext = np.concatenate([ctx, x])
        ext_obs = np.concatenate([finite_points(ctx), obs])
        ext_long = long_missing_mask(ext_obs, rate_hz, T)
        todo = ext_long[C:]
        if not todo.any():
            return out, done, counts
        srcs = self.sources if sources is None else sources
        closed = closed_blackout_mask(ext_obs)[C:] & todo
        if closed.any() and "time" in srcs and not self.prior_ok(J, skeleton):
            # whole frames lost with the joints seen on both sides (the history counts as
            # the near side): each joint's cubic spline through the clean history and the
            # window. Only where no learned prior knows the skeleton (marker sets, BVH):
            # where one does, its fill was closer to the truth (see closed_blackout_mask)
            from ..core.interpolate import interpolate_spline

            temporal, _ = interpolate_spline(np.where(ext_obs[..., None], ext, np.nan), ext_obs)
            if bones is not None and len(bones) == 0:
                from ..core.corotating import corotating_blackouts

                temporal = corotating_blackouts(temporal, ext_obs)
            use = closed & finite_points(temporal[C:])
            out[use] = temporal[C:][use]
            done |= use
            counts["time"] = int(use.sum())
            todo = todo & ~done
            if not todo.any():
                return out, done, counts
        short = ~ext_obs & ~ext_long
        if short.any():
            # short gaps are the solver's: give the sources a linear guess there (marked
            # observed) so they fit only the long gaps (PCA cost grows with the number of
            # distinct missing-joint patterns)
            from ..core.interpolate import interpolate_linear

            guess, ok = interpolate_linear(np.where(ext_obs[..., None], ext, np.nan), ext_obs)
            use_short = short & ok & finite_points(guess)
            ext = np.where(use_short[..., None], guess, ext)
            ext_obs = ext_obs | use_short
        limited = np.zeros_like(done)  # fills the excursion limit applies to (see excursion_sources)
        travelling = None  # the body's net speed reaches travel_speed_mps (computed once, when asked)
        pca_then_prior = "pca" in srcs and "prior" in srcs[srcs.index("pca") + 1:]
        if PRIOR_FIRST_WHILE_TRAVELLING and pca_then_prior and h is not None and self.prior_ok(J, skeleton):
            travelling = self._travelling(ext, ext_obs, rate_hz)
            if travelling:  # the gait is the prior's to fill, not PCA's (module doc): prior just before pca
                i = srcs.index("pca")
                srcs = srcs[:i] + ("prior",) + tuple(s for s in srcs[i:] if s != "prior")
        for src in srcs:
            left = todo & ~done
            if not left.any():
                break
            est = mask = None
            try:
                if src == "pca" and h is not None and self._history_ok(h, left.any(axis=0), rate_hz):
                    from ..core.pca_fill import PcaGapFiller

                    est, mask = PcaGapFiller(blackout_window=T + C).fit(h).fill(ext, ext_obs)
                elif src == "prior" and self.prior_ok(J, skeleton):
                    from ..prior.init import fill_long_gaps, prior_window_frames

                    # the newest frames only, one prior window when the solver's window fits in it (the
                    # prior's latency budget): the context before it is not worth a second and third fit
                    s0 = max(0, len(ext) - max(T, prior_window_frames(rate_hz)))
                    est, mask = np.full_like(ext, np.nan), np.zeros_like(ext_obs)
                    est[s0:], mask[s0:] = fill_long_gaps(ext[s0:], ext_obs[s0:], rate_hz, min_gap_frames=1,
                                                         skeleton=skeleton, method=self.prior_method)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError):
                # a source that fails on this window (e.g. an SVD that does not converge):
                # counted, and the next source is tried
                counts["errors"] = counts.get("errors", 0) + 1
                continue
            if est is None:
                continue
            est, mask = est[C:], mask[C:]
            use = left & mask & finite_points(est)
            out[use] = est[use]
            done |= use
            if use.any() and (src in self.excursion_sources or (src == "prior" and self.prior_limited_limbs)):
                if travelling is None:
                    travelling = self._travelling(ext, ext_obs, rate_hz)
                if not travelling:  # a travelling body's limbs move with its gait: no limit (module doc)
                    if src in self.excursion_sources:
                        limited |= use
                    else:
                        from ..prior.init import limb_joint_mask

                        limited |= use & limb_joint_mask(J, self.prior_limited_limbs, skeleton)[None, :]
            if use.any():
                counts[src] = int(use.sum())
        if unlimited is not None:
            limited &= ~np.asarray(unlimited, dtype=bool)
        limited &= ext_obs.any(axis=0)[None, :]  # a joint never seen here has no baseline to keep it near
        if gain is not None and limited.any():
            # keep each model fill within the joint's recent range of motion of its
            # continuity baseline (hold from the last observed sample; linear once the
            # far end is in the window): see core/excursion.py
            full = ext.copy()
            full[C:][done] = out[done]
            fmask = np.zeros_like(ext_obs)
            fmask[C:] = done
            ref = None if bones is None else anchor_reference(full, ext_obs, parents_from_bones(bones, J))
            lim = limit_excursion(full, ext_obs, fmask, max(1, int(round(EXCURSION_HORIZON_S * rate_hz))),
                                  gain=gain, reference=ref)[C:]
            out[limited] = lim[limited]
        # a joint missing for the whole window with no source: hold its last clean value
        empty = ~obs.any(axis=0) & ~done.any(axis=0)
        if empty.any() and history is not None and len(history):
            h = np.asarray(history, dtype=np.float64)
            fin = finite_points(h)
            has = fin.any(axis=0) & empty
            if has.any():
                last = (len(h) - 1) - np.argmax(fin[::-1], axis=0)  # newest finite frame per joint
                cols = np.flatnonzero(has)
                out[:, cols] = h[last[cols], cols][None]
                done[:, cols] = True
                counts["hold"] = int(T * len(cols))
        return out, done, counts

    def _travelling(self, positions: np.ndarray, observed: np.ndarray, rate_hz: float) -> bool:
        """True when the body's net speed over ``positions`` reaches ``travel_speed_mps``."""
        if self.travel_speed_mps is None:
            return False
        return travel_speed(positions, observed, rate_hz) >= self.travel_speed_mps

    def _history_ok(self, history: np.ndarray, joints: np.ndarray, rate_hz: float) -> bool:
        h = np.asarray(history)
        if h.ndim != 3 or len(h) == 0:
            return False
        fin = finite_points(h)
        need = max(1, int(round(self.min_history_s * rate_hz)))
        return int((fin[:, joints].all(axis=1) & (fin.sum(axis=1) >= BLACKOUT_JOINTS)).sum()) >= need

    def prior_start(self, positions: np.ndarray, observed: np.ndarray, rate_hz: float, state: Any, init: Any):
        """(state, init) with the prior's D(E(Y)) as the solver's start (issue 4 item 4).

        Warm windows: the frames entering the window (``state.fresh`` trailing frames,
        which the solver would otherwise start from their linearly gap-filled data) start
        from D(E(Y)) (observed joints keep their values); cold windows: ``init`` = D(E(Y)).
        """
        from dataclasses import replace

        from ..prior.init import prior_initial_guess

        guess = prior_initial_guess(positions, observed, rate_hz, method="encode")
        if not np.isfinite(guess).all():
            return state, init
        if state is None:
            return None, guess if init is None else init
        fresh = int(getattr(state, "fresh", 0) or 0)
        if fresh <= 0 or getattr(state, "A", None) is None or state.A.shape != guess.shape:
            return state, init
        new = slice(guess.shape[0] - fresh, None)
        fields = {}
        for name in ("A", "N", "Ct"):
            arr = getattr(state, name).copy()
            arr[new] = guess[new]
            fields[name] = arr
        return replace(state, fresh=0, **fields), init

    def __call__(
        self,
        positions: np.ndarray,
        confidence: np.ndarray | None,
        bones: np.ndarray,
        bone_lengths: np.ndarray | None,
        rate_hz: float,
        config: Any = None,
        state: Any = None,
        init: np.ndarray | None = None,
        history: np.ndarray | None = None,
        skeleton: Skeleton | None = None,
    ) -> Any:
        x = np.asarray(positions, dtype=np.float64)
        finite = finite_points(x)
        conf = finite.astype(np.float64) if confidence is None else np.where(finite, confidence, 0.0)
        obs = conf > 0
        replaced = None  # (T, J) samples the stages below replaced: flagged recovered
        released = None  # (T, J) frozen inferred samples released: carried to the next window
        state, released_before = split_state(state)
        plant_weight = None  # foot support's correction weight (T, J), when it planted a leg
        swapped = None  # (T, J) samples relabelled from their left/right twin
        along_ray = None  # (T, J) depths thrown along the camera ray, moved back
        if self.undo_swaps and skeleton is not None:
            # left/right limbs the sensor exchanged for a few frames (streaming/swaps.py)
            from .swaps import unswap_window

            # exchanged back, not flagged recovered: they are observed samples relabelled,
            # and the clean history must keep them so the next window sees the same labels
            x, swapped = unswap_window(x, obs, skeleton, rate_hz, history)
        if self.release_frozen and skeleton is not None:
            # inferred limbs that stopped bending (the sensor's frozen or drifting guess,
            # core/frozen.py) become missing: the bridge and the solver fill them
            frozen = frozen_release(x, conf, bones, rate_hz, self._layout(skeleton), released_before)
            if frozen.any():
                x = np.where(frozen[..., None], np.nan, x)
                conf = np.where(frozen, 0.0, conf)
                obs = conf > 0
                replaced = released = frozen
        if self.verify_inferred and skeleton is not None:
            # inferred limbs the rest of the body contradicts (frozen or drifting): the
            # bridging fill takes over (core/inferred.py); before foot support, which
            # marks the legs it plants with a lowered confidence of its own
            x, conf, verified = self._verify_inferred(x, conf, obs, bones, rate_hz, history, skeleton)
            if verified is not None:
                replaced = verified if replaced is None else (replaced | verified)
        if self.repair_depth and skeleton is not None and skeleton.name in CAMERA_SPACE_SKELETONS:
            # joints the sensor read the background's (or an occluder's) depth for, thrown along
            # their camera ray (core/ray_depth.py): moved back along it to their bone's length, a
            # low-confidence observation the window pipeline smooths with the rest
            from ..core.ray_depth import FLOOR_M, PROVISIONAL_FLOOR_M, provisional_lengths, repair_ray_depth

            lengths, floor_m = bone_lengths, FLOOR_M
            b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
            if lengths is None and len(b):
                # the body's lengths are not known yet (its first second): the window's own
                # samples say enough to tell a limb thrown metres back (a person walking into view)
                twins = mirror_bones(skeleton) if np.array_equal(b, skeleton.bone_array) else None
                lengths = provisional_lengths(seen_bone_lengths(x, conf > 0, b), twins)
                floor_m = PROVISIONAL_FLOOR_M
            x, along_ray = repair_ray_depth(x, conf, bones, lengths, floor_m=floor_m, rate_hz=rate_hz)
            if along_ray.any():
                conf = np.where(along_ray, self.fill_confidence, conf)
                replaced = along_ray if replaced is None else (replaced | along_ray)
        if self.foot_support and skeleton is not None:
            # legs the sensor folded up while a foot must be on the floor (streaming/support.py);
            # undone before the window pipeline, which then smooths the fix with everything else
            from .support import plant_window

            x, weight = plant_window(x, obs, skeleton, bones, bone_lengths, rate_hz, history, trusted=conf >= 1.0)
            if weight.any():
                plant_weight = weight
                replaced = (weight > 0.5) if replaced is None else (replaced | (weight > 0.5))
                conf = np.where(weight > 0, np.minimum(conf, FILL_CONFIDENCE * 2), conf)
        if self.release_dislocated and skeleton is not None:
            # a hand or foot held far off its bone's length for a run of frames (collapsed
            # onto the wrist, thrown off): not a measurement, the gap fill replaces it
            # (core/dislocated.py); after foot support, whose planted legs have their lengths
            from ..core.dislocated import dislocated_ends, parent_relative_fill

            dislocated = dislocated_ends(x, conf, bones, bone_lengths, rate_hz, joints=self._layout(skeleton)[0])
            if dislocated.any():
                # put back on the parent from the offsets around the run, a low-confidence
                # observation the window pipeline smooths with the rest (no solver run for it)
                x = parent_relative_fill(x, dislocated, obs, bones, bone_lengths)
                placed = dislocated & finite_points(x)
                conf = np.where(placed, self.fill_confidence, np.where(dislocated, 0.0, conf))
                x = np.where((dislocated & ~placed)[..., None], np.nan, x)
                obs = conf > 0
                replaced = dislocated if replaced is None else (replaced | dislocated)
        dropped = released  # samples whose older windows' values the engine's blend drops
        if self.release_jumps and len(bones):
            # a limb that jumped as one piece for a few frames (core/limb_jumps.py): its own
            # bones keep their lengths, so the robust fit would follow it; the gap fill replaces it
            from ..core.limb_jumps import jumped_limbs

            jumped = jumped_limbs(x, obs, bones, bone_lengths, rate_hz)
            if jumped.any():
                x = np.where(jumped[..., None], np.nan, x)
                conf = np.where(jumped, 0.0, conf)
                obs = conf > 0
                replaced = jumped if replaced is None else (replaced | jumped)
                # an older window saw the jump at its newest frames, still open, and kept it:
                # the engine's blend drops what it left there, as for a frozen release
                dropped = jumped if released is None else (released | jumped)
        res = self._solve(x, conf, obs, bones, bone_lengths, rate_hz, config, state, init, history,
                          None if skeleton is None else skeleton.name, released)
        # the live topic carries these (streaming/live_carry.py); a depth thrown along its ray it
        # repairs itself, frame by frame, where a window's pose would be a hop old
        judged = np.zeros(x.shape[:2], dtype=bool)
        if replaced is not None:
            judged |= replaced
        if along_ray is not None:
            judged &= ~along_ray
        if swapped is not None:
            judged |= swapped
        if judged.any():
            res.info[JUDGED_KEY] = judged
        if replaced is None:
            return res
        res = _with_recovered(res, replaced)
        if released is not None:
            res.state = ReleaseState(res.state, released)  # frozen runs go on being released
        if dropped is not None:
            res.info[RELEASED_KEY] = dropped  # the engine's blend drops older windows that kept them
        if plant_weight is not None:
            # the planted legs are a guess with the sensor hip's jitter in them (core/support.py)
            from ..core.support import SupportConfig, smooth_planted

            res.positions = smooth_planted(res.positions, plant_weight, rate_hz, SupportConfig().planted_smooth_s)
        return res

    def _layout(self, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
        """The skeleton's limb joints and left/right twins (``frozen_release.limb_layout``), cached."""
        layout = self._limb_joints.get(skeleton.name)
        if layout is None:
            layout = self._limb_joints[skeleton.name] = limb_layout(skeleton)
        return layout

    def _verify_inferred(self, x, conf, obs, bones, rate_hz, history, skeleton: Skeleton):
        """(positions, confidence, replaced mask or None): long runs of inferred samples
        moved toward the bridging fill where they part from it (core/inferred.py)."""
        inferred = obs & (conf < 1.0)
        if not inferred.any() or history is None or len(history) < VERIFY_HISTORY_S * rate_hz:
            # the fill is only trusted over the sensor's guess once the body has a clean
            # history to train PCA on (the prior alone, at a stream's start, differs from
            # window to window by more than the sensor's inferred limbs do)
            return x, conf, None
        T = len(x)
        # only near samples the sensor tracked: a limb inferred for long (a seated person's
        # legs under a desk) has no tracked sample to anchor the fill, which then guesses
        # worse than the sensor; the gate fades with the distance in time so neighbouring
        # windows, which see different stretches, decide alike
        from ..core.inferred import replacement_weight, tracked_proximity

        near = tracked_proximity(conf >= 1.0, rate_hz)
        cand = inferred & (missing_run_lengths(~inferred) >= open_gap_frames(T, rate_hz)) & (near > 0)
        if not cand.any():
            return x, conf, None
        from ..limbs import limb_groups

        # the prior only: PCA trains on the clean history, which holds the sensor's
        # inferred guesses themselves and so agrees with them
        if not self.prior_ok(x.shape[1], skeleton.name):
            return x, conf, None
        fill, done, _ = self.bridge(x, obs & ~cand, rate_hz, history, skeleton.name, bones, sources=("prior",),
                                    excursion_gain=VERIFY_EXCURSION_GAIN)
        limbs = [side for pair in limb_groups(skeleton) for side in pair]
        w = replacement_weight(x, fill, done, cand, limbs) * near
        if not (w > 0).any():
            return x, conf, None
        x = np.where((w > 0)[..., None], x + w[..., None] * (np.nan_to_num(fill) - x), x)
        conf = np.where(w > 0, (1.0 - w) * conf + w * self.fill_confidence, conf)
        return x, conf, w > 0.5

    def _solve(self, x, conf, obs, bones, bone_lengths, rate_hz, config, state, init, history, skeleton_name=None,
               released=None):
        """Bridge long gaps, then the base solver (``__call__`` after the real-sensor stages)."""
        kwargs: dict[str, Any] = {"state": state, "init": init}
        if config is not None:
            kwargs["config"] = config
        if obs.all() or not obs.any():
            return self.base(x, conf, bones, bone_lengths, rate_hz, **kwargs)
        if not long_missing_mask(obs, rate_hz).any():
            if self.prior_init == "always" and self.prior_ok(x.shape[1], skeleton_name):
                kwargs["state"], kwargs["init"] = self.prior_start(x, obs, rate_hz, state, init)
            return self.base(x, conf, bones, bone_lengths, rate_hz, **kwargs)
        free = None if self.limit_released else released
        filled, bridged, counts = self.bridge(x, obs, rate_hz, history, skeleton_name, bones, unlimited=free)
        if not bridged.any():
            return self.base(x, conf, bones, bone_lengths, rate_hz, **kwargs)
        conf_in = np.where(bridged, self.fill_confidence, conf)
        if init is not None:
            init = np.where(bridged[..., None], filled, init)
            kwargs["init"] = init
        if self.prior_init != "off" and self.prior_ok(x.shape[1], skeleton_name) and not (obs | bridged).all():
            kwargs["state"], kwargs["init"] = self.prior_start(filled, obs | bridged, rate_hz, state, kwargs["init"])
        return _with_recovered(self.base(filled, conf_in, bones, bone_lengths, rate_hz, **kwargs), bridged, counts)
