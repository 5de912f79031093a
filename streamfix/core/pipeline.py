"""The default ``streamfix`` cleaning of one window: robust detection, solver, isometry.

Why not Algorithm 1 alone (issue 2's measured facts): its l1 data term lets E absorb
only what its optimum says is error, and at heavy corruption (80 %) that optimum is
far from the truth; on real Kinect data its wavelet term removes little of the
jitter. The pipeline therefore wraps the solver in robust statistics:

1. **Robust temporal regression** (outlier detection, :mod:`streamfix.core.robust_fit`).
   Each coordinate channel is fitted by a local quadratic (tricube kernel, half-width
   ``h`` frames) with Tukey-biweight weights, by iteratively reweighted least squares started from a running median and
   with a graduated scale ``c`` (10 -> 5 -> 2 -> 1 cm; Tukey's biweight
   ``w = (1 - (r/c)^2)^2`` for ``|r| < c``). Corrupted entries of the protocol are
   uniform over +-25 cm, clean ones lie on a smooth curve: the clean samples are the
   mode of the residual distribution even when 80 % of entries are corrupted, which a
   redescending M-estimator finds and the l1 term does not. Sensor confidence
   multiplies the weights (Kinect *inferred* joints count half: low confidence, not
   missing). **Window by rigidity:** the fit is run for each candidate window
   (``candidate_windows_s``, 2-9 frames at 30 Hz, 8-36 at 120 Hz); further candidates,
   for windows too short or fast for any local fit, are the running median +
   Savitzky-Golay (unbiased for symmetric noise however heavy) and the best fit blended
   with it where the fit's inlier support is below ``blend_support`` of a full window.
   The candidate whose bone lengths vary least over time (median absolute deviation,
   :func:`_bone_spread`; for marker sets the most rigid marker pairs) wins. A skeleton's
   bones are rigid, so this needs no ground truth: a fit that follows the clean samples
   keeps them constant, one that chased corrupted samples does not. Ties go to the
   shortest window (least bias). **The median alone only where it is unbiased**
   (``fallback_max_residual_ratio``): a smoother's bias on fast motion flattens a whole limb
   alike and so keeps its bones rigid, which the score cannot see, while noise on every
   sample always scores the smoother more rigid; so the running median + Savitzky-Golay
   stands alone only where its median absolute residual is at most 1.5x the chosen fit's
   (under heavy corruption the fit's residual is as large as the median's). Without it,
   short fast takes of the sensor protocol's noise came out worse than the input
   (``benchmarks/results/sensor.md``, per take). **Nor where it follows a jump**
   (``fallback_worst_bone_quantile``): each bone's median over time ignores a limb that
   jumps for a few frames, so a median that follows the jump scores as rigid as a fit that
   rejects it; each frame's worst bone does not (:func:`_worst_bone_quantile`), and the
   median stands alone only where that is no worse than the fit's. **Scored where the output is used**:
   ``serve`` publishes a frame from windows where it lies 6-15 frames from the newest, so the
   engine has the score taken over the newest frames its blend uses (``score_newest_frames``:
   lookahead + hop + crossfade, plus the widest fit's half-width); over the whole 2 s window, a wide fit that
   suited the already-published older frames was used where a hand moved fast (KERAAL,
   ``tests/test_paired_engine_quality.py``). The file schedule's windows are used whole.
   **Frame by frame** (``local_width_s``): the window's speed and corruption change within
   it, so the fitted half-width is chosen per frame, by the same rigidity scored over the
   frames around it, and blended between
   neighbouring candidates (:mod:`streamfix.core.local_width`); that composite fit
   (``"local"``) takes the window-wide fit's place and competes with the median
   candidates as that fit did.
   ``benchmarks/results/`` has what it changed on each protocol.
2. **Outliers become missing.** An observed entry whose residual exceeds
   ``outlier_threshold_m`` is replaced by the robust fit (the protocol's noise is
   per coordinate, so this acts per coordinate); the rest keep their observed value.
   On a rigid skeleton, a flagged group of joints whose raw bones keep their lengths
   while the fit's do not is fast motion, not an outlier, and keeps its samples
   (``keep_rigid_motion``, :mod:`streamfix.core.rigid_motion`).
3. **Noise-matched smoothing** (:mod:`streamfix.core.adaptive_smoothing`). What is left
   after outlier removal is either motion detail (keep it) or white sensor noise (smooth
   it). The two are told apart by how the robust scale of local-quadratic residuals grows with the window: white noise
   gives nearly the same scale at half-widths 2 and 4 frames (ratio ~1.3-1.6 on all
   our Kinect files), fitting real motion leaves a bias growing like h^4 (ratio 2-4 on
   clean or lightly corrupted mocap). When the ratio is below ``white_noise_ratio``
   and the scale above ``smooth_floor_m``, every observed sample is replaced by the
   weighted local quadratic over ``smooth_window_s`` (zero lag, matched to the rate).
   Real depth-sensor jitter is temporally correlated, which raises the ratio, and slow
   rehabilitation-style motion wants the longer window; the gate is soft (full
   smoothing at ``white_noise_ratio``, none at ``white_noise_ratio_max``, blended
   between), so a window's noisy ratio does not flip it. The blend spans where the two
   kinds overlap: Kinect v1's correlated noise on UI-PRMD reaches up into it (a blend
   ending lower left many of those windows smoothed only in part, and their
   jitter in the output), exact mocap in short or slow windows reaches down into it
   (smoothing that costs the paper protocol accuracy): gate and window were chosen
   against Vicon on UI-PRMD (``benchmarks/bench_paired.py``) with the paper protocol's
   bars checked alongside (``benchmarks/bench_accuracy.py``).
4. **Solver for what is missing** (around it, :mod:`streamfix.core.window_gaps`).
   Joint-frames with no observation (gaps) are recovered by
   :func:`streamfix.core.alm.solve` (mode ``solver_mode``, low rank + isometry
   [+ wavelet]) run on the cleaned window, where spatial correlation across joints beats
   temporal interpolation over long gaps. **Short gaps in time** (``time_gap_s``): a gap
   closed within half a second is each joint's cubic spline through its samples, and the
   solver sees those values as data. The low-rank model describes the window as a whole:
   a forearm and hand lost for 4 frames of a fast swing came back at their mean pose, far
   off, where the spline was close; over a second or more the spline overshoots
   and the solver, with the bridge's long-gap fills, does better (measured with limbs and
   single joints dropped for 4-40 frames on the CMU and Xia takes; ``tests/test_short_gaps_and_blackouts.py``).
   The solver's offset from
   the observations at each gap's two ends is ramped linearly across the gap
   (``boundary_correction``), so a filled run meets its neighbours without a jump. A gap
   still open at the window's newest frames has no far end: its fill is kept near the
   joint's last pose relative to the limb's anchor, a bound that widens over its first
   half second (``open_gap_gain``, ``open_gap_ramp_s``; the streaming engine publishes
   those newest frames, where the unanchored solve jumped tens of centimetres).
   Observed joint-frames keep the robust stage's values. Skipped when nothing is
   missing: run after outlier removal on complete data the solver changed AJE from a
   little better to several times worse (it only helps a little at 80 %), and run on the raw
   input from the robust estimate as ``init`` it walks back to its own optimum (far off at 80 %).
5. **Bone-length projection** (:mod:`streamfix.core.bone_projection`). Every bone is pulled to its length (given, or the
   median over the window's confident outlier-free frames), which the paper's model
   does only softly: Jacobi constraint iterations (position-based dynamics,
   :func:`streamfix.core.bone_projection.project_bone_lengths_pbd`) split each bone's length error between its ends
   in proportion to their inverse confidence, so an *inferred* joint moves twice as
   far as a tracked one. Measured against the Gauss-Newton step of Eq. (20) with
   Z2 = 0 (:func:`streamfix.core.bone_projection.project_bone_lengths`, ``projection="gauss_newton"``), which has no
   line search and left part of the Kinect bone CV in place (more steps made it
   worse on some files), 50 iterations lower AJE and ABE on every CMU/Xia case tried.
   **Noisy joints take the correction** (:mod:`streamfix.core.bone_projection`): a joint whose
   window residual scale (``joint_noise_scale``) is clearly above the body's typical
   joint's moves in proportion to its variance (a Kinect thumb or hand, not the wrist,
   shoulder and spine behind it), and on noisy joints the correction is smoothed over
   ``projection_smooth_s`` (``smooth_projection``): a steady length correction
   applied along a short bone whose direction jitters would add jitter; samples the
   window filled or replaced keep the exact correction (no sensor jitter behind them,
   and a smoothed one left part of a thumb's replaced 4-frame spike). Exact
   samples (mocap) keep equal shares. **Length play on tracked bones**
   (:mod:`streamfix.core.length_tolerance`): a bone between two tracked, precise joints
   keeps its own length, smoothed over ``projection_play_smooth_s``, while that is within
   ``projection_tolerance`` of the target (less ``projection_tolerance_noise`` x the ends'
   noise), and is pulled only to that band's edge beyond: a sensor's joint centres shift
   with the pose, and a length error does not say which end is wrong. **Lost joints
   yield**: a run of outlier flags at least ``projection_failure_s`` long
   (``tracking_failures``) holds the temporal fit's guess, and takes the length
   errors of its bones as a missing joint would.

How well it does, against what, is measured by the benchmarks and written to
``benchmarks/results/`` (``accuracy.md`` for the paper's protocols, ``paired.md`` against
Vicon, ``sensor.md`` for realistic sensor errors); numbers are not copied here, where they
would go stale. In the product this function runs per window inside the streaming engine
(:mod:`streamfix.streaming.engine`), which is what ``streamfix clean`` and ``serve`` output.

Arrays: positions ``(T, J, 3)`` metres (NaN = missing), confidence ``(T, J)`` in [0, 1].
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import alm, kernels
from .adaptive_smoothing import motion_adaptive_smooth
from .bone_projection import (joint_noise_scale, noise_share, project_bone_lengths, project_pbd,
                              projection_inverse_mass, smooth_projection, tracking_failures)
from .excursion import EXCURSION_GAIN
from .filters import median_savgol
from .interpolate import interpolate_linear, interpolate_spline, missing_run_lengths
from .isometry import bone_length_deviations, estimate_bone_lengths
from .length_tolerance import LENGTH_TOLERANCE, NOISE_MULTIPLE, PLAY_SMOOTH_S, length_targets, length_tolerance
from .local_poly import kernel_mass, residual_scale
from .local_width import frame_bone_deviations, frame_sums, local_width_index, take_fractional
from .points import any_xyz, finite_points
from .rigid_motion import rigid_motion
from .robust_fit import robust_fit
from .window_gaps import fill_short_gaps, limit_open_gaps, spline_closed_gaps

__all__ = ["PipelineConfig", "WindowResult", "clean_window"]


@dataclass(frozen=True)
class PipelineConfig:
    """Knobs of :func:`clean_window` (units in the names; see the module doc for the stages)."""

    # stage 1: robust temporal regression
    scales_m: tuple[float, ...] = (0.10, 0.05, 0.02, 0.01)
    candidate_windows_s: tuple[float, ...] = (0.067, 0.1, 0.133, 0.2, 0.3)
    local_width_s: float | None = 1.0 / 6.0  # half-span (s) each frame's half-width is scored over; None = one per window
    local_width_smooth_s: float = 0.1  # half-span (s) the per-frame choice is averaged over
    h_min_frames: int = 2
    median_fallback: bool = True
    fallback_margin: float = 1.0
    # the median candidate alone only while its residual is at most this x the best fit's (None = always)
    fallback_max_residual_ratio: float | None = 1.5
    # ... and only while, at this quantile over frames of each frame's worst bone deviation, it
    # breaks bones no more than the fit (None = not asked): see _worst_bone_quantile
    fallback_worst_bone_quantile: float | None = 0.9
    blend_support: float = 0.5
    min_bone_m: float = 0.02
    outlier_threshold_m: float = 0.01
    keep_rigid_motion: bool = True  # flagged samples whose bones stay rigid are kept (core.rigid_motion)
    # the estimators' rigidity is scored on the window's newest this many frames plus the widest
    # candidate half-width (None: the whole window); the streaming engine sets the frames its
    # blend takes from a window, the hop before them and the crossfade (module doc, stage 1)
    score_newest_frames: int | None = None
    inferred_weight: float = 0.5
    # stage 4: solver for missing joint-frames
    use_solver: bool = True
    solver_mode: str = "li"
    solver_max_iter: int = 300
    solver_tol: float = 1e-5
    boundary_correction: bool = True
    short_gap_s: float = 0.1  # every gap at most this long (s): local quadratic across it, no solver
    # closed gaps at most this long (s) are each joint's cubic spline, the solver's data (None = none)
    time_gap_s: float | None = 0.5
    # a gap still open at the window's end stays near the joint's last pose (core.window_gaps.limit_open_gaps):
    # within open_gap_gain x its recent range of motion (None = off), a bound reached over open_gap_ramp_s
    open_gap_gain: float | None = EXCURSION_GAIN
    open_gap_ramp_s: float = 0.5
    # stage 3: smoothing matched to the noise level and rate
    smooth_floor_m: float = 1e-4
    white_noise_ratio: float = 1.9  # at or below: smooth fully
    white_noise_ratio_max: float = 2.3  # at or above: do not smooth; blended in between
    smooth_window_s: float = 0.7
    smooth_short_s: float | None = 0.2  # None: one span (smooth_window_s) for every joint
    smooth_bias_m: tuple[float, float] = (0.006, 0.015)
    # stage 5: bone-length projection
    project_bones: bool = True
    projection: str = "pbd"
    projection_iterations: int = 50
    projection_steps: int = 4
    projection_gamma: float = 1e4
    projection_noise_floor_m: float | None = 0.001  # None: shares by confidence only, correction not smoothed
    projection_smooth_s: float = 0.2  # zero-lag span (s) of the correction on noisy joints; 0 = none
    projection_noisy_ratio: float = 2.0  # noisier than this x the median joint: takes more of the correction
    projection_tolerance: float = LENGTH_TOLERANCE  # tracked bones keep this fraction of length play (0 = exact)
    projection_tolerance_noise: float = NOISE_MULTIPLE  # the play narrows by this x the bone's noise scale
    projection_play_smooth_s: float = PLAY_SMOOTH_S  # the kept play is smoothed over this span (s): slow, not jitter
    projection_failure_s: float | None = 1.0 / 6.0  # outlier runs this long (s) take length errors as missing joints do


@dataclass
class WindowResult:
    """Output of :func:`clean_window`.

    positions ``(T, J, 3)`` m; recovered ``(T, J)`` True where a joint-frame was not
    observed or had a coordinate replaced as an outlier; state: the solver state (None
    when the solver was not run, i.e. nothing was missing); iterations/converged: the
    solver's (0 / True when it was not needed); info: what was measured and chosen
    (candidate bone spreads, chosen estimator and window, outlier fraction, noise
    scales, smoothing window, bone lengths).
    """

    positions: np.ndarray
    recovered: np.ndarray
    state: alm.SolverState | None = None
    iterations: int = 0
    converged: bool = True
    info: dict = field(default_factory=dict)


def _median_abs(resid: np.ndarray) -> float:
    """Median absolute residual (m) over the observed coordinates (NaN elsewhere); 0 for none."""
    r = np.abs(resid[np.isfinite(resid)])
    return float(np.median(r)) if r.size else 0.0


def _estimate(x: np.ndarray, obs3: np.ndarray, fit: np.ndarray, resid: np.ndarray, cfg: "PipelineConfig") -> np.ndarray:
    """Stage 2 for one candidate: observed inliers kept, everything else from ``fit``."""
    inlier = obs3 & (np.abs(resid) <= cfg.outlier_threshold_m)  # NaN residual: not an inlier
    return np.where(inlier, x, fit)


def _rigid_pairs(x: np.ndarray, obs: np.ndarray, rate_hz: float, k: int = 60) -> np.ndarray:
    """For a marker set without bones: the ``k`` pairs whose distance varies least.

    Ranked on the running median + Savitzky-Golay estimate (robust to the outliers the
    ranking must not be fooled by), via :func:`streamfix.core.pca_gapfill.estimate_rigid_pairs`.
    """
    try:
        from .pca_gapfill import estimate_rigid_pairs
    except ImportError:  # pragma: no cover
        return np.zeros((0, 2), dtype=np.intp)
    if x.shape[1] < 2:
        return np.zeros((0, 2), dtype=np.intp)
    med = median_savgol(x, rate_hz, obs)
    return estimate_rigid_pairs(med, obs, k=k, min_common=max(3, min(30, x.shape[0] // 2)))


def _scored_frames(n_frames: int, newest: int | None, widest_half_width: int) -> slice:
    """The frames of a window its estimators are scored on: the newest ``newest`` plus the
    widest fit's half-width (the older side of their kernels), or all (``newest`` None, or
    that many frames or more)."""
    if newest is None:
        return slice(None)
    n = int(newest) + int(widest_half_width)
    return slice(n_frames - n, None) if n < n_frames else slice(None)


def _bone_spread(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray, min_bone_m: float) -> float:
    """Model-selection score (m): mean over bones of the median |l_t - median_t l|.

    A skeleton's bones are rigid, so an estimate that follows the clean samples keeps
    their lengths nearly constant, while one that chased corrupted samples does not.
    Only frames where both ends are observed, and bones longer than ``min_bone_m``
    (BVH hierarchies contain zero-length bones), count. Needs no ground truth.
    """
    dev = bone_length_deviations(positions, observed, bones, min_bone_m)
    dev = dev[np.isfinite(dev)]
    return float(dev.mean()) if dev.size else 0.0


def _frame_deviations(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray,
                      min_bone_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`streamfix.core.local_width.frame_bone_deviations` (``(T, B)`` deviations, ``(B,)``
    counted), from the compiled bone lengths when the kernels are compiled (the same values)."""
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    if not (kernels.COMPILED and len(b)):
        return frame_bone_deviations(positions, observed, b, min_bone_m)
    per_bone, per_frame = kernels.bone_spread_deviations(positions, observed, b, min_bone_m, frames=True)
    return per_frame, np.isfinite(per_bone)


def _frame_bone_deviation(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray,
                          min_bone_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`streamfix.core.local_width.frame_bone_deviation` of one estimate (:func:`_frame_deviations`)."""
    return frame_sums(*_frame_deviations(positions, observed, bones, min_bone_m))


def _worst_bone_quantile(positions: np.ndarray, observed: np.ndarray, bones: np.ndarray, min_bone_m: float,
                         quantile: float) -> float:
    """The ``quantile`` over frames of each frame's largest ``|l_t - median_t l|`` (m) over the
    bones :func:`_bone_spread` counts; 0 where no bone is seen.

    Why: :func:`_bone_spread` takes each bone's median over time, so an estimate that follows
    a limb jumping for a few frames (a sensor's gross failure) scores as rigid as one that
    rejects it; the jump stretches at least the bone joining the limb to the body there, which
    each frame's worst bone shows.
    """
    dev, counted = _frame_deviations(positions, observed, bones, min_bone_m)
    dev = dev[:, counted]
    worst = np.max(np.where(np.isfinite(dev), dev, -1.0), axis=1, initial=-1.0)
    worst = worst[worst >= 0]
    return float(np.quantile(worst, quantile)) if worst.size else 0.0


# --------------------------------------------------------------------------- the pipeline
def clean_window(
    positions: np.ndarray,
    confidence: np.ndarray | None,
    bones: np.ndarray,
    bone_lengths: np.ndarray | None,
    rate_hz: float,
    config: PipelineConfig = PipelineConfig(),
    state: alm.SolverState | None = None,
    init: np.ndarray | None = None,
) -> WindowResult:
    """Clean one window ``(T, J, 3)`` m at ``rate_hz`` (see the module doc for the stages).

    ``confidence`` ``(T, J)`` (None = 1 where finite); ``bone_lengths`` ``(B,)`` m or None
    (median over the window's most confident frames, after outlier removal);
    ``state`` / ``init`` warm-start the solver stage (see :func:`streamfix.core.alm.solve`).
    """
    cfg = config
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3), got {x.shape}")
    n_frames, n_joints, _ = x.shape
    finite = finite_points(x)
    if confidence is None:
        conf = finite.astype(np.float64)
    else:
        conf = np.asarray(confidence, dtype=np.float64)
        if conf.shape != (n_frames, n_joints):
            raise ValueError(f"confidence must be {(n_frames, n_joints)}, got {conf.shape}")
        conf = np.where(finite, conf, 0.0)
    obs = conf > 0
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    info: dict = {}
    if not obs.any():
        return WindowResult(np.full_like(x, np.nan), np.ones_like(obs), None, 0, False, info)

    # prior weight: tracked 1, inferred (0 < c < 1) -> inferred_weight, missing 0
    prior = np.where(conf >= 1.0, 1.0, np.where(obs, cfg.inferred_weight, 0.0))

    # stage 1: one robust fit per candidate window; keep the one whose bones stay rigid
    obs3 = np.repeat(obs[..., None], 3, axis=2)
    rigid = bones if len(bones) else _rigid_pairs(x, obs, rate_hz)  # markers: pairs found in the data
    widths = sorted({max(cfg.h_min_frames, int(round(w * rate_hz))) for w in cfg.candidate_windows_s})
    scored = _scored_frames(n_frames, cfg.score_newest_frames, widths[-1])

    def spread(est: np.ndarray) -> float:
        return _bone_spread(est[scored], obs[scored], rigid, cfg.min_bone_m)

    spreads = {}
    local = cfg.local_width_s is not None and len(widths) > 1 and len(rigid) > 0
    fits, supports, dev_sums, dev_counts = [], [], [], []
    best = None  # one half-width for the window (local off): the most rigid
    for h in widths:
        fit_h, resid_h, sup_h = robust_fit(x, prior, h, cfg.scales_m)
        est_h = _estimate(x, obs3, fit_h, resid_h, cfg)
        if local:
            s_h, n_h = _frame_bone_deviation(est_h, obs, rigid, cfg.min_bone_m)
            fits.append(fit_h)
            supports.append(sup_h)
            dev_sums.append(s_h)
            dev_counts.append(n_h)
            continue
        spreads[h] = spread(est_h)
        if best is None or spreads[h] < spreads[best[0]]:
            best = (h, fit_h, resid_h, sup_h, est_h)
    if local:
        # each frame takes the half-width whose bones stay rigid around it (core.local_width).
        # The composite is the window's fit everywhere. It used to be kept only where the
        # window as a whole was as rigid as the best single half-width, for a limb thrown
        # rigidly for a few frames (a frame's mean over bones dilutes its one stretched bone,
        # so the short fit that follows it wins there); but that guard also dropped the
        # composite wherever one width was a hair more rigid over the window, and the
        # per-frame choice everywhere measured better on every protocol (jumps, spikes, real
        # sensors: benchmarks/results/). The thrown-limb case stays a known failure
        # (tests/test_core_pipeline.py).
        index = local_width_index(np.array(dev_sums), np.array(dev_counts),
                                  int(round(cfg.local_width_s * rate_hz)), int(round(cfg.local_width_smooth_s * rate_hz)))
        h, chosen = None, "local"
        fit = take_fractional(np.array(fits), index)
        resid = np.where(obs3, x - fit, np.nan)
        fit_est = _estimate(x, obs3, fit, resid, cfg)
        spreads["local"] = spread(fit_est)
        sup = take_fractional(np.array(supports), index)
        # of a full window: where a fit has less inlier support, the median helps
        full = np.interp(index, np.arange(len(widths)), [kernel_mass(w) for w in widths])[:, None, None]
        info["local_half_width_frames"] = np.interp(index, np.arange(len(widths)), widths)
    else:
        h, fit, resid, sup, fit_est = best
        chosen = h
        full = kernel_mass(h)
    if cfg.median_fallback:
        # the median's answer is unbiased for symmetric noise, however heavy: a fallback
        # for windows too short or too fast for any local fit to find the clean samples,
        # alone or blended where the chosen fit has little inlier support
        fit_key = chosen
        med = median_savgol(x, rate_hz, obs)
        med_resid = np.where(obs3, x - med, np.nan)
        spreads["median_savgol"] = spread(med)
        a = np.clip(sup / (full * cfg.blend_support), 0.0, 1.0)
        blend = np.where(np.isfinite(med), a * fit + (1.0 - a) * np.nan_to_num(med), fit)
        blend_resid = np.where(obs3, x - blend, np.nan)
        spreads["blend"] = spread(_estimate(x, obs3, blend, blend_resid, cfg))
        # the median's bias on fast motion flattens a whole limb alike, which keeps its bones
        # rigid, so the score cannot see it: its residual can (module doc, stage 1)
        r_fit = _median_abs(resid)
        ratio = _median_abs(med_resid) / r_fit if r_fit > 0 else np.inf
        info["median_residual_ratio"] = ratio
        biased = cfg.fallback_max_residual_ratio is not None and ratio > cfg.fallback_max_residual_ratio
        median_wins = not biased and spreads["median_savgol"] < cfg.fallback_margin * min(spreads[fit_key],
                                                                                       spreads["blend"])
        q = cfg.fallback_worst_bone_quantile
        if median_wins and q is not None and len(rigid):
            # ... nor can the window's score see it follow a limb that jumps for a few frames (a
            # minority of frames, which each bone's median over time ignores); each frame's
            # worst bone can: the median stands alone only where it breaks bones no more than
            # the fit does there
            t_med = _worst_bone_quantile(med[scored], obs[scored], rigid, cfg.min_bone_m, q)
            t_fit = _worst_bone_quantile(fit_est[scored], obs[scored], rigid, cfg.min_bone_m, q)
            info["worst_bone_m"] = {"median_savgol": t_med, fit_key: t_fit}
            median_wins = t_med <= t_fit
        if median_wins:
            chosen, fit, resid = "median_savgol", med, med_resid
        elif spreads["blend"] < spreads[fit_key]:
            chosen, fit, resid = "blend", blend, blend_resid
    info.update(half_width_frames=h, estimator=chosen, bone_spread_m=spreads)

    # stage 2: outlying coordinates take the robust fit
    outlier = obs3 & ~(np.abs(resid) <= cfg.outlier_threshold_m)  # NaN residual: an outlier
    if cfg.keep_rigid_motion and len(rigid):
        # a flagged group whose raw bones stay rigid is motion too fast for the fit, not an outlier
        motion = rigid_motion(x, np.where(outlier, fit, x), any_xyz(outlier), obs, rigid, cfg.min_bone_m)
        outlier &= ~motion[..., None]
        info["rigid_motion_kept"] = int(motion.sum())
    cleaned = np.where(obs3 & ~outlier, x, fit)
    info["outlier_fraction"] = info["contamination"] = float(outlier[obs3].mean()) if obs3.any() else 0.0

    # stage 3: is what is left white sensor noise (smooth it) or motion detail (keep it)?
    wc = np.repeat(prior, 3, axis=1).reshape(n_frames, -1)
    yc = np.where(obs3, cleaned, 0.0).reshape(n_frames, -1)
    s_small, s_large = (residual_scale(yc, wc, hh) for hh in (2, 4))
    ratio = s_large / s_small if s_small > 0 else np.inf
    info.update(noise_small_m=s_small, noise_large_m=s_large, noise_ratio=ratio)
    # a soft gate: the ratio of one 2 s window is a noisy statistic, and a hard threshold
    # flipped smoothing on and off between neighbouring windows (seams, and smoothing of
    # exact mocap whose window happened to dip below it)
    hi_ratio = max(cfg.white_noise_ratio_max, cfg.white_noise_ratio)
    z = 1.0 if ratio <= cfg.white_noise_ratio else float(np.clip((hi_ratio - ratio) / max(hi_ratio - cfg.white_noise_ratio, 1e-12), 0.0, 1.0))
    share = z * z * (3.0 - 2.0 * z)
    # how much of this window is sensor noise: the streaming engine smooths that share of
    # its blended output (streamfix.streaming.solver_api.NOISE_SHARE_KEY)
    info["sensor_noise_share"] = share if s_large > cfg.smooth_floor_m else 0.0
    if s_large > cfg.smooth_floor_m and share > 0:
        sm, hs = motion_adaptive_smooth(yc, wc, rate_hz, cfg.smooth_window_s, cfg.smooth_short_s,
                                        cfg.smooth_bias_m)
        cleaned = np.where(obs3, share * sm.reshape(x.shape) + (1.0 - share) * cleaned, cleaned)
        info["smooth_half_width_frames"] = hs
        info["smooth_share"] = share

    # stage 4: missing joint-frames from the solver (or interpolation: short gaps only, or
    # no solver)
    missing = ~obs
    iterations, converged, out_state = 0, True, None
    if missing.any():
        base = np.where(obs3, cleaned, np.nan)
        short = max(0, int(round(cfg.short_gap_s * rate_hz)))
        # short and closed: a joint that has just vanished at the window's newest frames is
        # the solver's (the other joints say where it went; its neighbours in time do not)
        closed = obs[0].all() and obs[-1].all()
        if cfg.use_solver and closed and missing_run_lengths(obs).max() <= short:
            filled = fill_short_gaps(cleaned, obs, short)
            info["short_gaps_only"] = True
            out_state = state  # the solver did not run: its warm start carries on to the next window
        elif cfg.use_solver:
            # closed gaps up to time_gap_s: each joint's cubic spline (core.window_gaps), which
            # the solver takes as data; the solver fills the rest
            solve_base, timed = base, np.zeros_like(obs)
            if cfg.time_gap_s is not None:
                solve_base, timed = spline_closed_gaps(base, obs, max(1, int(round(cfg.time_gap_s * rate_hz))))
            solve_obs = obs | timed
            if (solve_obs | ~obs.any(axis=1)[:, None]).all():
                # nothing left for the solver: the splines fill every missing sample, closed gaps
                # above and frames with no joint seen below (a dropped frame at the window's edge,
                # which is no closed gap), so a solve's values would all be thrown away (on a
                # Kinect file, 600-frame solves for one dropped first frame: a real share of its cleaning)
                filled = solve_base
                info["solve_skipped"] = True
                out_state = state  # the solver did not run: its warm start carries on
            else:
                params = alm.SolverParams(mode=cfg.solver_mode, max_iter=cfg.solver_max_iter, tol=cfg.solver_tol)
                res = alm.solve(solve_base, solve_obs, bones, bone_lengths, params, init=init, state=state)
                filled = res.positions
                iterations, converged, out_state = res.iterations, res.converged, res.state
                if cfg.boundary_correction:
                    # the solver's offset from the observations at each gap's two ends, ramped
                    # linearly across the gap, so a filled run meets its neighbours without a jump
                    offset, _ = interpolate_linear(np.where(obs3, cleaned - filled, np.nan), obs)
                    filled = filled + np.nan_to_num(offset)
                if cfg.open_gap_gain is not None:
                    filled = limit_open_gaps(filled, obs, bones, rate_hz, cfg.open_gap_gain, cfg.open_gap_ramp_s)
                if timed.any():
                    filled = np.where(timed[..., None], solve_base, filled)
            info["time_filled"] = int(timed.sum())
        if cfg.use_solver:
            blackout = ~obs.any(axis=1)
            if blackout.any():
                # a frame with no joint observed is a missing column of the low-rank model,
                # which nothing in it can recover (the solve left such frames far off);
                # time can: each joint's cubic spline through its observed frames (also
                # across short blackouts, where it beats the local quadratic on fast motion)
                filled[blackout] = interpolate_spline(base, obs, frames=np.flatnonzero(blackout))[0]
                info["blackout_frames"] = int(blackout.sum())
        else:
            filled, _ = interpolate_linear(base, obs)
        cleaned = np.where(obs3, cleaned, filled)

    recovered = missing | any_xyz(outlier)  # filled or replaced: no sensor reading behind them

    # stage 5: bone-length projection
    if cfg.project_bones and len(bones):
        good = obs & ~any_xyz(outlier)  # observed and kept: the samples whose lengths count
        if bone_lengths is None:
            bl = estimate_bone_lengths(cleaned, bones, good, np.where(good, conf, 0.0))
            bl = np.where(np.isfinite(bl), bl, estimate_bone_lengths(cleaned, bones))
        else:
            bl = np.asarray(bone_lengths, dtype=np.float64)
        if cfg.projection == "pbd":
            noise = joint_noise_scale(x, cleaned, obs3 & ~outlier)
            failed = tracking_failures(any_xyz(outlier), rate_hz, cfg.projection_failure_s)
            inv_mass = projection_inverse_mass(np.where(failed, 0.0, conf), obs & ~failed, noise,
                                               cfg.projection_noise_floor_m, cfg.projection_noisy_ratio)
            targets = bl
            band = (length_tolerance(bones, bl, noise, conf, good, cfg.projection_tolerance,
                                     cfg.projection_tolerance_noise) if cfg.projection_tolerance > 0 else None)
            if band is not None and band.any():  # no play anywhere (noisy ends, guesses): the lengths themselves
                play_frames = int(round(cfg.projection_play_smooth_s * rate_hz))
                targets = length_targets(cleaned, bones, bl, band, play_frames)
            projected = project_pbd(cleaned, bones, targets, cfg.projection_iterations, inv_mass)
            share = noise_share(noise, cfg.projection_noise_floor_m)
            cleaned = smooth_projection(cleaned, projected, share, rate_hz, cfg.projection_smooth_s,
                                        exact=recovered)
            info["joint_noise_m"] = noise
        else:
            cleaned = project_bone_lengths(cleaned, bones, bl, cfg.projection_steps, cfg.projection_gamma)
        info["bone_lengths"] = bl

    return WindowResult(cleaned, recovered, out_state, iterations, converged, info)
