"""How plausible is a pose window? Leave-one-limb-out residuals of the learned prior (onnxruntime only).

Why: a real sensor fails by putting a whole limb in the wrong place (left and right
swapped, an inferred leg frozen or drifting, a hand jumping a metre). Each such limb is
self-consistent, so bone lengths do not catch it; but the rest of the body tells where
the limb should be. For every limb (the four of ``streamfix.canonical.CANONICAL_LIMBS``
plus the head) we hide it, fit the prior's latent space to the *rest* of the window
(D(z*), Lohit et al. Eq. 1) and measure how far the observed limb lies from where the
prior puts it. All limb variants of all windows go through one batched
Levenberg-Marquardt solve.

Usage (any layout ``streamfix.canonical`` maps, any length and rate)::

    from streamfix.prior.plausibility import limb_residuals
    score = limb_residuals(positions, observed, rate_hz)     # (T, J, 3) m, (T, J) bool
    score.limb_rms_m["left_arm"]      # RMS distance (m) of the observed left arm from the prediction
    score.joint_residual_m            # (T, J) m per layout joint (NaN: unobserved or not in a limb)
    score.worst_limb(baseline)        # the limb whose residual grew most against a clean window

How to read it: a limb that moves on its own (an arm raised while the rest stands still)
is legitimately hard to predict from the rest of the body, so a clean window's residuals
vary widely between limbs and movements (held-out UI-PRMD person). Compare each limb
with *its own* residual in recent windows the pipeline trusted (``worst_limb(baseline)``,
a ratio), not limbs with each other and not with a fixed number. On the held-out person
(tests/test_prior_canonical.py) a leg drifting 35 cm over 2 s raises its own residual over 2x
while the others barely change; swapping the arms raises the residuals of the whole window
(the body no longer fits), the swapped arms' most in standing movements.
Residuals are in the input's metres (de-normalised).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from streamfix.canonical import CANONICAL_JOINTS, CANONICAL_LIMBS, Layout, layout_for_joint_count, to_canonical

from ..core.interpolate import observed_mask
from .data import cut_windows, resample_masked
from .init import overlap_add
from .runtime import Prior, load_default_prior

__all__ = ["LimbResiduals", "limb_residuals", "PLAUSIBILITY_GROUPS"]

#: Joint groups hidden one at a time: the four limbs and the head (canonical indices).
PLAUSIBILITY_GROUPS: dict[str, tuple[int, ...]] = {**CANONICAL_LIMBS, "head": (CANONICAL_JOINTS.index("head"),)}


@dataclass
class LimbResiduals:
    """Leave-one-limb-out residuals of one motion window."""

    limb_rms_m: dict  # group name -> RMS distance (m) of its observed joint-frames from the prediction (NaN if none)
    canonical_residual_m: np.ndarray  # (T, 20) m, distance of each observed canonical joint from its prediction
    joint_residual_m: np.ndarray  # (T, J) m in the input layout (exact canonical joints only, else NaN)
    fit_rms_m: float  # RMS fit error of D(z*) on everything observed (m): how well the prior explains the window

    def worst_limb(self, baseline: "LimbResiduals | None" = None) -> tuple[str, float]:
        """(group, score) of the least plausible limb: the largest ratio of its RMS residual to ``baseline``'s
        (the same body in a window the pipeline trusted), or without a baseline the largest RMS (m)."""
        ref = baseline.limb_rms_m if baseline is not None else {}
        score = {k: v / ref[k] if baseline is not None else v for k, v in self.limb_rms_m.items()
                 if np.isfinite(v) and (baseline is None or (np.isfinite(ref.get(k, np.nan)) and ref[k] > 0))}
        if not score:
            return "", float("nan")
        name = max(score, key=score.get)
        return name, float(score[name])


def limb_residuals(
    positions: np.ndarray,
    observed: np.ndarray,
    rate_hz: float,
    *,
    prior: Prior | None = None,
    max_iter: int | None = None,
    method: str = "latent",
) -> LimbResiduals:
    """Leave-one-limb-out residuals of a (T, J, 3) metre window with mask (T, J), any mapped layout and rate.

    The window is mapped to the canonical joints, resampled to the prior's rate and cut
    into the prior's windows (half-window hop); for each window and each group of
    ``PLAUSIBILITY_GROUPS`` the group is hidden and D(z*) fitted to the rest; the
    predictions are blended back over time and compared with the observations.
    ``max_iter``: chord steps of each fit (None = the bridge's ``streamfix.prior.init.CHORD_STEPS``).
    ``method``: ``"latent"`` D(z*) or ``"encode"`` D(E(Y)), a fraction of the cost (no decoder-Jacobian
    call per variant; ``benchmarks/bench_prior.py`` times both) for a per-window check in a stream.
    """
    if method not in ("latent", "encode"):
        raise ValueError(f"method must be 'latent' or 'encode', got {method!r}")
    from .init import CHORD_DAMPING, CHORD_STEPS
    from .latent import fit_latent

    prior = prior or load_default_prior()
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3:
        raise ValueError(f"positions must be (T, J, 3), got {x.shape}")
    obs = observed_mask(x, observed)
    layout: Layout = layout_for_joint_count(x.shape[1])
    cx, cobs = to_canonical(x, obs, layout)
    n = x.shape[0]
    names = list(PLAUSIBILITY_GROUPS)
    xr, obr = resample_masked(cx, cobs, rate_hz, prior.rate_hz)
    wins, masks, starts = cut_windows(xr, obr, prior.window, prior.window // 2)
    wins = np.nan_to_num(wins)
    n_w, n_g = len(wins), len(names)
    # batch: [all observed, group 0 hidden, group 1 hidden, ...] for every window
    batch_m = np.repeat(masks[:, None], n_g + 1, axis=1)
    for g, name in enumerate(names):
        batch_m[:, g + 1, :, list(PLAUSIBILITY_GROUPS[name])] = False
    batch_x = np.repeat(wins[:, None], n_g + 1, axis=1)
    flat_x, flat_m = batch_x.reshape((-1,) + wins.shape[1:]), batch_m.reshape((-1,) + masks.shape[1:])
    if method == "latent":
        fit = fit_latent(prior, flat_x, flat_m, max_iter=CHORD_STEPS if max_iter is None else max_iter,
                         jacobian_steps=0, damping=CHORD_DAMPING)
        decoded, fit_rms_all = fit.decoded, fit.fit_rms_m.reshape(n_w, n_g + 1)[:, 0]
    else:
        decoded = prior.reconstruct(flat_x, flat_m)
        d2 = ((decoded.reshape((n_w, n_g + 1) + wins.shape[1:])[:, 0] - wins) ** 2).sum(-1)  # (W, T, J)
        fit_rms_all = np.sqrt((d2 * masks).sum(axis=(1, 2)) / np.maximum(3 * masks.sum(axis=(1, 2)), 1))
    dec = decoded.reshape((n_w, n_g + 1) + wins.shape[1:])
    pred = dec[:, 0].copy()  # every joint from the all-observed fit, then each group from its hidden fit
    for g, name in enumerate(names):
        idx = list(PLAUSIBILITY_GROUPS[name])
        pred[:, :, idx] = dec[:, g + 1][:, :, idx]
    valid = masks.any(axis=1).sum(axis=1) >= 3
    est = overlap_add(pred, starts, xr.shape[0], valid if valid.any() else None)
    if xr.shape[0] != n:
        from .init import _resample_full

        est = _resample_full(np.nan_to_num(est), prior.rate_hz, rate_hz, n)
    res = np.where(cobs, np.linalg.norm(np.nan_to_num(cx) - est, axis=-1), np.nan)
    limb_rms = {}
    for name in names:
        r = res[:, list(PLAUSIBILITY_GROUPS[name])]
        r = r[np.isfinite(r)]
        limb_rms[name] = float(np.sqrt(np.mean(r**2))) if r.size else float("nan")
    in_group = np.zeros(len(CANONICAL_JOINTS), dtype=bool)
    in_group[[j for g in PLAUSIBILITY_GROUPS.values() for j in g]] = True
    joint_res = np.where((layout.exact & in_group[layout.anchor_index])[None, :], res[:, layout.anchor_index], np.nan)
    n_obs = max(int(masks.sum()), 1)
    fit_rms = float(np.sqrt(np.sum(fit_rms_all ** 2 * masks.sum(axis=(1, 2))) / n_obs))
    return LimbResiduals(limb_rms, res, joint_res, fit_rms)
