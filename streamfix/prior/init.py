"""The prior as the solver's initialiser and as the filler of long-missing joints (onnxruntime only).

How the other layers call it
----------------------------
* Solver initialisation (pipeline / streaming engine, any window length and rate)::

      from streamfix.prior.init import prior_initial_guess
      init = prior_initial_guess(D, observed, rate_hz)          # (T, J, 3), no NaN
      params = solver_params_for_prior_init(D, observed)       # start the penalty ramp later
      result = streamfix.core.alm.solve(D, observed, bones, params=params, init=init)

  ``method="latent"`` (default) gives D(z*) (Eq. 1), ``method="encode"`` the cheaper
  D(E(Y)). Observed joints are returned unchanged (``keep_observed=True``), unobserved
  ones come from the prior. Cost: one batched call per 64-frame (30 Hz) window at hop 32.

* Streaming warm start (the new frames entering a window): instead of the constant-velocity
  extrapolation of ``SolverState.shifted(hop)``::

      state = prior_shifted_state(prev.state, hop, D, observed, rate_hz)
      result = streamfix.core.alm.solve(D, observed, bones, state=state)

  (D/observed: the *new* window, whose last ``hop`` frames are the new ones.)

* Joints missing for longer than the solver can bridge (streaming engine, ``clean``)::

      from streamfix.prior.init import fill_long_gaps
      filled, recovered = fill_long_gaps(D, observed, rate_hz, min_gap_frames=15)
      # recovered (T, J) bool: flag these samples as recovered in the output

  Every run of >= ``min_gap_frames`` missing frames of a joint gets D(z*)'s value,
  shifted by a linearly varying offset so that it meets the observed samples at both
  ends of the gap (an edge gap keeps the constant offset of its one observed end).
  The bridge passes it the newest ``prior_window_frames(rate_hz)`` frames (one latent fit
  per window solve) and keeps the excursion limit on the fills of the joints
  ``limb_joint_mask(J, ("left_arm", "right_arm"), skeleton)`` marks. When every joint to fill
  is one the canonical body lacks (an ear, a hand tip, a thumb) and its anchor (and the
  anchor's parent) is observed throughout, no latent fit is run: ``from_canonical`` places
  such a joint from its anchor alone, and the observed anchor is used in place of the
  prior's reconstruction of it (a pose estimator that loses an ear for seconds cost a latent
  fit every window, the larger part of its stream's cost).

D(z*) here is the chord method of ``streamfix.prior.latent``: one decoder-Jacobian call at
E(Y) and ``CHORD_STEPS`` damped steps on it, the cost that fits the streaming budget. Both
D(z*) and D(E(Y)) reconstruct each window twice, as it is and as its mirror image, and
average the two (``MIRROR_ENSEMBLE``).

All three accept the prior's own joints (the canonical 20) or any layout that
``streamfix.canonical`` maps (told apart by joint count: Kinect v2 25, Azure Kinect 32,
Kinect v1/UI-PRMD 22, COCO-17, BlazePose 33): the motion is mapped to the canonical
joints, reconstructed there and mapped back (``from_canonical``: joints that are not
canonical, such as hand tips, move with their anchor joint at their observed offset).
``prior_available()`` tells whether the prior handles a joint count, so callers can
skip it otherwise.
"""
from __future__ import annotations

import numpy as np

from streamfix.canonical import mirrored
from streamfix.core.interpolate import neighbour_observations, observed_mask

from .data import cut_windows, resample_masked
from .runtime import Prior, load_default_prior

__all__ = [
    "prior_initial_guess",
    "fill_long_gaps",
    "prior_available",
    "prior_window_frames",
    "limb_joint_mask",
    "overlap_add",
    "solver_params_for_prior_init",
    "prior_shifted_state",
    "PRIOR_INIT_RHO_FACTOR",
    "CHORD_STEPS",
    "CHORD_DAMPING",
    "MIRROR_ENSEMBLE",
]

# A solver started from the prior begins its penalty ramp (rho_k = eta^k rho0, Algorithm 1
# lines 15-17) at this multiple of the cold-start rho0 = 1.25/||D||_2, as the solver's own
# warm start does (it restarts at rho_prev / eta^12, well up the ramp a cold solve climbed).
# Measured on the held-out windows at test OTP 50 % (benchmarks/bench_prior.py): the later
# the start, the fewer iterations than a cold solve, at about the same RMSE.
PRIOR_INIT_RHO_FACTOR = 1.3**20

# D(z*) as the bridge and the solver start run it: one decoder-Jacobian call at E(Y), then this many
# Levenberg-Marquardt steps on that Jacobian (the chord method, one decoder call each) from this initial
# damping (relative to diag(Jr^T Jr)): the latency budget of a streamed window. More steps on the same
# Jacobian do not lower the held-out error (less damping raises it); each further Jacobian call (the fit
# run to convergence) lowers it a little, at much of the budget each (benchmarks/bench_prior.py).
CHORD_STEPS = 1
CHORD_DAMPING = 0.3

# Each window is also reconstructed as its mirror image (x negated, left and right joints swapped) and the
# mirrored reconstruction mirrored back is averaged with the direct one. The model saw every training
# window both ways, but it is not exactly symmetric; the two reconstructions err differently on a pose
# it knows less well, and their mean errs less (held-out cells, benchmarks/bench_prior.py). The mirror
# images ride in the same batch as the windows (the encoder and decoder run once for both).
MIRROR_ENSEMBLE = True


def prior_available(n_joints: int, prior: Prior | None = None, skeleton: str | None = None) -> bool:
    """True when the (default) prior handles skeletons of ``n_joints`` joints (its own or a mapped layout).

    Pass ``skeleton`` (the skeleton's registry name) where known: joint counts alone
    cannot tell a 32-marker C3D file from an Azure Kinect body.
    """
    try:
        p = prior or load_default_prior()
    except (FileNotFoundError, ValueError):
        return False
    if skeleton is not None:
        return skeleton == p.card.get("skeleton") or _layout_of(p, n_joints, skeleton) is not None
    return p.n_joints == n_joints or (_layout_of(p, n_joints) is not None)


def _layout_of(prior: Prior, n_joints: int, skeleton: str | None = None):
    """The ``streamfix.canonical.Layout`` of the motion when the prior is canonical and the motion is not, else None."""
    from streamfix.canonical import LAYOUTS, layout_for_joint_count

    if prior.card.get("skeleton") != "canonical":
        return None
    if skeleton is not None:
        lay = LAYOUTS.get(skeleton)
        return None if lay is None or lay.name == "canonical" or lay.n_joints != n_joints else lay
    if n_joints == prior.n_joints:
        return None
    try:
        return layout_for_joint_count(n_joints)
    except ValueError:
        return None


def limb_joint_mask(n_joints: int, limbs: tuple[str, ...], skeleton: str | None = None,
                    prior: Prior | None = None) -> np.ndarray:
    """(J,) bool: the joints of a layout on the canonical ``limbs`` (``streamfix.canonical.CANONICAL_LIMBS`` names).

    A layout joint belongs to a limb when its canonical anchor does (a hand tip goes with the
    hand); all False when the (default) prior does not map the layout.
    """
    from streamfix.canonical import CANONICAL_LIMBS

    p = prior or load_default_prior()
    canon = np.zeros(len(p.card["joints"]), dtype=bool)
    for name in limbs:
        canon[list(CANONICAL_LIMBS[name])] = True
    if p.card.get("skeleton") == "canonical" and (skeleton == "canonical" or n_joints == p.n_joints and skeleton is None):
        return canon
    layout = _layout_of(p, n_joints, skeleton)
    return np.zeros(n_joints, dtype=bool) if layout is None else canon[layout.anchor_index]


def prior_window_frames(rate_hz: float, prior: Prior | None = None) -> int:
    """Frames at ``rate_hz`` that one window of the (default) prior covers (its T frames at its own rate)."""
    p = prior or load_default_prior()
    return max(1, int(np.floor(p.window * rate_hz / p.rate_hz)))


def overlap_add(windows: np.ndarray, starts: np.ndarray, n_frames: int, valid: np.ndarray | None = None) -> np.ndarray:
    """Blend (W, T, J, 3) windows placed at ``starts`` into (n_frames, J, 3) with sin^2 weights.

    ``valid`` (W,) bool drops windows; frames no valid window covers are NaN.
    """
    w_len = windows.shape[1]
    if len(starts) == 1 and (valid is None or valid[0]) and starts[0] == 0 and n_frames <= w_len:
        return np.array(windows[0, :n_frames], dtype=np.float64)  # one window: its own values
    weight = np.sin(np.pi * (np.arange(w_len) + 0.5) / w_len) ** 2 + 1e-3
    win_w = np.ones(len(starts)) if valid is None else np.asarray(valid, dtype=np.float64)
    idx = (starts[:, None] + np.arange(w_len)[None, :]).ravel()
    keep = idx < n_frames
    acc = np.zeros((n_frames,) + windows.shape[2:])
    wsum = np.zeros(n_frames)
    wts = (win_w[:, None] * weight[None, :]).ravel()[keep]
    np.add.at(acc, idx[keep], windows.reshape((-1,) + windows.shape[2:])[keep] * wts[:, None, None])
    np.add.at(wsum, idx[keep], wts)
    out = acc / np.maximum(wsum, 1e-300)[:, None, None]
    out[wsum <= 0] = np.nan
    return out


def _resample_full(x: np.ndarray, rate_in: float, rate_out: float, n_out: int) -> np.ndarray:
    """Linear resampling of a complete (T, J, 3) array to ``n_out`` frames at ``rate_out`` (edges held)."""
    n = x.shape[0]
    f = np.clip(np.arange(n_out) * (rate_in / rate_out), 0, n - 1)
    i0 = np.floor(f).astype(np.intp)
    i1 = np.minimum(i0 + 1, n - 1)
    w = (f - i0)[:, None, None]
    return (1 - w) * x[i0] + w * x[i1]


def prior_initial_guess(
    positions: np.ndarray,
    observed: np.ndarray,
    rate_hz: float,
    *,
    prior: Prior | None = None,
    method: str = "latent",
    keep_observed: bool = True,
    max_iter: int = CHORD_STEPS,
    skeleton: str | None = None,
) -> np.ndarray:
    """A complete (T, J, 3) metre estimate from the prior for any T and rate.

    The motion is resampled to the prior's rate (30 Hz), cut into windows of the
    prior's length at half-window hop (a shorter motion is one window padded with
    unobserved frames), each window reconstructed (``method``: ``"latent"`` = D(z*),
    ``"encode"`` = D(E(Y))), blended by overlap-add and resampled back. With
    ``keep_observed`` observed joints keep their input values. Windows that saw fewer
    than 3 joints are ignored and the frames only they covered are interpolated in time
    between their neighbours' estimates. A motion with nothing observed is returned as all-NaN.
    ``skeleton``: the motion's layout name (``streamfix.canonical.LAYOUTS``); None = told by joint count.
    """
    prior = prior or load_default_prior()
    x = np.asarray(positions, dtype=np.float64)
    layout = _resolve_layout(prior, x, skeleton)
    obs = np.asarray(observed, dtype=bool) & np.isfinite(x).all(axis=-1)
    if obs.shape != x.shape[:2]:
        raise ValueError(f"observed must be {x.shape[:2]}, got {obs.shape}")
    est = _estimate(prior, x, obs, rate_hz, layout, method, max_iter)
    if keep_observed and (layout is None or np.isfinite(est).any()):  # a mapped motion it saw nothing of: all NaN
        est[obs] = x[obs]
    return est


def _resolve_layout(prior: Prior, x: np.ndarray, skeleton: str | None):
    """The mapped layout of (T, J, 3) positions (None: the prior's own joints); ValueError for any other shape."""
    layout = _layout_of(prior, x.shape[1], skeleton) if x.ndim == 3 else None
    if x.ndim != 3 or x.shape[2] != 3 or (x.shape[1] != prior.n_joints and layout is None):
        raise ValueError(f"positions must be (T, {prior.n_joints}, 3) for the prior's skeleton or (T, J, 3) of a "
                         f"layout streamfix.canonical maps, got {x.shape}")
    return layout


def _estimate(prior: Prior, x: np.ndarray, obs: np.ndarray, rate_hz: float, layout, method: str,
              max_iter: int, joints: np.ndarray | None = None) -> np.ndarray:
    """``prior_initial_guess(..., keep_observed=False)`` of validated input (``obs`` observed and finite).

    ``layout``: ``_resolve_layout``'s answer; the motion is mapped to the canonical joints and back
    (``joints`` (J,) bool: only these layout joints are wanted, ``canonical._from_canonical``)."""
    if layout is not None:
        from streamfix.canonical import _from_canonical, _matrices, _to_canonical

        maps = _matrices(layout)
        cx, cobs = _to_canonical(x, obs, maps)
        if joints is not None and _carried_by_observed_anchors(maps, cobs, joints):
            # the wanted joints (an ear, a hand tip) follow their anchors by from_canonical's rule (anchor
            # + k (anchor - its parent) + d, fitted where the joint was seen): with the anchors observed,
            # those place them, with no latent fit for the prior's copy of them
            return _from_canonical(cx, maps, x, obs, joints)
        est = _estimate(prior, cx, cobs, rate_hz, None, method, max_iter)
        if not np.isfinite(est).any():
            return np.full_like(x, np.nan)
        return _from_canonical(est, maps, x, obs, joints)
    n = x.shape[0]
    if n == 0 or not obs.any():
        return np.full_like(x, np.nan)
    if method not in ("latent", "encode"):
        raise ValueError(f"method must be 'latent' or 'encode', got {method!r}")
    # at the prior's own rate the motion is used as it is (resample_masked would copy it)
    xr, obr = (x, obs) if rate_hz == prior.rate_hz else resample_masked(x, obs, rate_hz, prior.rate_hz)
    w_len = prior.window
    wins, masks, starts = cut_windows(xr, obr, w_len, w_len // 2, fill=0.0)
    mirror = prior.mirror if MIRROR_ENSEMBLE else None
    n_win = wins.shape[0]
    if mirror is not None:  # the mirror images ride in the same batch
        m_wins, m_masks = mirrored(wins, masks, mirror)
        wins, masks = np.concatenate([wins, m_wins]), np.concatenate([masks, m_masks])
    if method == "latent":
        from .latent import fit_latent

        # the chord method (dD/dz of E(Y) kept): one Jacobian call per window and max_iter decoder calls,
        # the latency budget of the streaming bridge; more steps hardly change the held-out scores
        # (benchmarks/bench_prior.py measures both)
        rec = fit_latent(prior, wins, masks, max_iter=max_iter, jacobian_steps=0, damping=CHORD_DAMPING).decoded
    else:
        rec = prior.reconstruct(wins, masks)
    if mirror is not None:
        masks = masks[:n_win]
        rec = 0.5 * (rec[:n_win] + mirrored(rec[n_win:], masks, mirror)[0])
    # a window that saw too little of the body (fewer than 3 joints ever) says nothing about it
    valid = masks.any(axis=1).sum(axis=1) >= 3
    if not valid.any():
        valid = masks.any(axis=(1, 2))
    est = overlap_add(rec, starts, xr.shape[0], valid)
    if np.isnan(est).any():  # frames no valid window covers: linear interpolation in time
        from streamfix.core.interpolate import interpolate_linear

        est = interpolate_linear(est, np.isfinite(est).all(axis=-1))[0]
    if xr.shape[0] != n:
        est = _resample_full(est, prior.rate_hz, rate_hz, n)
    return est


def _carried_by_observed_anchors(maps, canonical_observed: np.ndarray, joints: np.ndarray) -> bool:
    """True when every joint in ``joints`` (J,) bool is a layout joint that is no canonical joint
    and its anchor and the anchor's parent (``canonical._from_canonical``'s line) are observed
    in every frame of ``canonical_observed`` (T, 20)."""
    from streamfix.canonical import _PARENT_INDEX

    wanted = np.flatnonzero(joints)
    if wanted.size == 0 or maps.exact[wanted].any():
        return False
    anchors = maps.anchor[wanted]
    return bool(canonical_observed[:, np.union1d(anchors, _PARENT_INDEX[anchors])].all())


def solver_params_for_prior_init(D: np.ndarray, observed: np.ndarray, base=None, factor: float = PRIOR_INIT_RHO_FACTOR):
    """``SolverParams`` (``base`` or the defaults) with rho0 = ``factor`` x the cold-start 1.25/||D_c||_2.

    D_c is D centred the solver's default way (one mean per coordinate over the observed
    entries, unobserved entries 0), laid out as the paper's 3T x S matrix.
    """
    from dataclasses import replace

    from streamfix.core.alm import SolverParams

    base = base if base is not None else SolverParams()
    x = np.asarray(D, dtype=np.float64)
    obs3 = np.broadcast_to((np.asarray(observed, dtype=bool) & np.isfinite(x).all(axis=-1))[..., None], x.shape)
    if not obs3.any():
        return base
    centred = np.where(obs3, x - np.nanmean(np.where(obs3, x, np.nan), axis=(0, 1)), 0.0)
    paper = centred.transpose(0, 2, 1).reshape(-1, x.shape[1])  # 3T x S (Eq. 1 layout)
    rho0 = 1.25 / max(float(np.linalg.norm(paper, 2)), 1e-12)
    return replace(base, rho0=rho0 * factor)


def prior_shifted_state(
    state,
    hop: int,
    positions: np.ndarray,
    observed: np.ndarray,
    rate_hz: float,
    *,
    prior: Prior | None = None,
    method: str = "encode",
):
    """``state.shifted(hop)`` with the ``hop`` new frames' positions (A, N, W^T C) from the prior.

    ``positions``/``observed`` are the new window (T, J, 3) / (T, J) (its last ``hop``
    frames are the new ones). Observed joints of the new frames keep their values, the
    others come from the prior (``method`` "encode" = D(E(Y)), the cheaper; "latent" = D(z*)).
    """
    from dataclasses import replace

    shifted = state.shifted(hop)
    if hop <= 0:
        return shifted
    guess = prior_initial_guess(positions, observed, rate_hz, prior=prior, method=method)
    if not np.isfinite(guess[-hop:]).all():
        return shifted
    new = slice(shifted.A.shape[0] - hop, None)
    fields = {}
    for name in ("A", "N", "Ct"):
        arr = getattr(shifted, name).copy()
        arr[new] = guess[-hop:]
        fields[name] = arr
    return replace(shifted, **fields)


def fill_long_gaps(
    positions: np.ndarray,
    observed: np.ndarray,
    rate_hz: float,
    *,
    min_gap_frames: int,
    prior: Prior | None = None,
    estimate: np.ndarray | None = None,
    skeleton: str | None = None,
    method: str = "latent",
) -> tuple[np.ndarray, np.ndarray]:
    """Fill runs of >= ``min_gap_frames`` missing frames per joint from D(z*); returns (positions, filled mask).

    Observed samples and shorter gaps are returned untouched (short gaps stay NaN for
    the solver or interpolation to handle). ``estimate`` may pass a precomputed
    ``prior_initial_guess(..., keep_observed=False)`` to avoid a second prior run.
    ``method``: ``"latent"`` D(z*) (default) or ``"encode"`` D(E(Y)), much cheaper
    (see ``benchmarks/results/prior.json`` for both costs and accuracies).
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = observed_mask(x, observed)
    n = obs.shape[0]
    out = np.where(obs[..., None], x, np.nan)
    if n == 0 or obs.all() or not obs.any():
        return out, np.zeros_like(obs)
    prev, nxt = neighbour_observations(obs)
    run = nxt - prev - 1  # length of the gap each missing sample sits in
    fill = ~obs & (run >= min_gap_frames)
    if not fill.any():
        return out, fill
    if estimate is not None:
        p = estimate
    else:
        prior = prior or load_default_prior()
        # only the joints with samples to fill are read from the estimate
        p = _estimate(prior, x, obs, rate_hz, _resolve_layout(prior, x, skeleton), method, CHORD_STEPS,
                      joints=fill.any(axis=0))
    # only the samples to fill: offsets at the gap's observed ends, blended linearly across it
    t_f, j_f = np.nonzero(fill)
    pv, nx = prev[t_f, j_f], nxt[t_f, j_f]
    has_p, has_n = pv >= 0, nx < n
    # the observed end before and after the gap; an edge gap uses its one observed end on both sides
    pc, nc = np.where(has_p, pv, np.minimum(nx, n - 1)), np.where(has_n, nx, np.maximum(pv, 0))
    seen = (has_p | has_n)[:, None]  # else the joint is never observed: the prior's value as it is
    d_prev = np.where(seen, x[pc, j_f] - p[pc, j_f], 0.0)  # x is observed (finite) at pc, nc where seen
    d_next = np.where(seen, x[nc, j_f] - p[nc, j_f], 0.0)
    a = ((t_f - pv) / (nx - pv))[:, None]  # in (0, 1): pv < t_f < nx
    out[t_f, j_f] = p[t_f, j_f] + (1 - a) * d_prev + a * d_next
    return out, fill
