"""PCA gap filling with a training set (Li, Yu, Kieu, Vuong, Zhang 2020, "PCA-based
robust motion data recovery", IEEE Access 8).

Three estimators, as derived in the paper (motion matrix ``B`` is ``m x n``: ``m``
frames, ``n = 3J`` coordinates; a 0/1 *template* marks the missing entries and is
applied to every training sample ``A_i`` to give the incomplete ``A_i^(0)``):

* Eq. (1)-(4), training set = one long sequence cut into pieces stacked vertically,
  ``A = (A_1; ...; A_K)``: ``U`` = eigenvectors of ``A^T A`` (Eq. 1),
  ``U_i^(0)`` of ``A_i^(0)T A_i^(0)``, ``A_i U = A_i^(0) U_i^(0) T`` (Eq. 2) solved for
  the ``r x r`` ``T`` by least squares (Eq. 3), then ``B* = B U_B^(0) T U^T`` (Eq. 4).
  -> :func:`eq4_estimate` (matrix level), :func:`fill_gaps` (positions level).
* Eq. (5)-(8), training set = short pieces from different sources side by side,
  ``A = (A_1, ..., A_K)``: ``V`` = eigenvectors of ``A A^T`` (Eq. 5),
  ``V^T A_i = F V_i^(0)T A_i^(0)`` (Eq. 6), ``F`` by least squares (Eq. 7),
  ``B* = V F V_B^(0)T B`` (Eq. 8). This is Eq. (4) on transposed matrices (the paper
  says so: "no essential difference except the form of input matrix A").
  -> :func:`eq8_estimate`, :func:`fill_gaps` with ``layout="pieces"``.
* Eq. (9)-(16), whole frames missing: ``V`` = first ``r`` eigenvectors of ``A A^T``
  (temporal basis over the ``m`` frames of a window, Eq. 9), split into the rows of
  present frames ``V~`` and of missing frames ``V^``; coefficients by the weighted
  least squares of Eq. (13)-(14), ``alpha* = (V~^T W V~)^-1 V~^T W B~``, and the
  missing rows ``B^ = V^ alpha*`` (Eq. 15/16).
  -> :func:`eq16_estimate`, :func:`fill_blackouts` (module :mod:`streamfix.core.pca_blackouts`).

The rank rule and training data are in :mod:`streamfix.core.pca_training`, the
matrix-level Eq. (1)-(8) in :mod:`streamfix.core.pca_estimators`, the rigid marker pairs
in :mod:`streamfix.core.rigid_pairs`; their public names are importable from here too.
Frames are normalised by :mod:`streamfix.core.pca_normalise`, the boundary correction is
:mod:`streamfix.core.pca_boundary`, and the Eq. (8) layout at the positions level is
:mod:`streamfix.core.pca_pieces`. This module fills partial gaps in positions
(:func:`fill_gaps`: templates, local templates and their partner ranking); :mod:`streamfix.core.pca_fill` composes it with the blackout estimate into
the whole-take :func:`~streamfix.core.pca_fill.pca_fill` and the streaming
:class:`~streamfix.core.pca_fill.PcaGapFiller`.

Choices the paper leaves open, made here and documented:

* **Rank rule** (:func:`choose_rank`): ``r`` is the smallest number of leading
  eigenvalues of the training Gram matrix (after removing the training mean) whose
  sum reaches ``energy`` of the total: ``DEFAULT_ENERGY = 0.9999`` (99.99 % of the
  variance) for Eq. (4)/(8), capped by ``r_max`` (60) and by what the template
  leaves observable. For Eq. (16) the energy rule (0.999, on offset-free training
  trajectories) gives the largest ``r``; the columns actually used (<= that) and
  the weight scale are then picked by Eq. (13) on the training windows, because a
  temporal basis that is too rich extrapolates wildly into a blackout.
* **Basis alignment**: Eq. (2) assumes the individual eigenbases ``U_i^(0)``,
  ``U_B^(0)`` are expressed consistently, but an eigen-decomposition fixes each
  eigenvector only up to sign (and up to a rotation among close eigenvalues). Each
  individual basis is therefore rotated onto the pooled incomplete training basis
  by orthogonal Procrustes; this keeps every span (hence Eq. 2's premise) unchanged
  and makes the result independent of the eigen-solver's arbitrary choices.
* **Templates** (:func:`fill_gaps`): samples are grouped by template and Eq. (1)-(4)
  run once per template. With ``n_partners=None`` the template is the paper's: the
  frame's observed joints predict all its missing ones. By default the matrix holds
  one missing joint and the k observed joints whose distance to it varies least in
  training ("local templates"; on the CMU takes this fills 100-frame gaps much
  closer than the whole-body template); k is chosen per joint among
  ``DEFAULT_PARTNERS = (3, 6)`` by the error on the joint's observed samples
  within 30 frames of its gaps (observed data only, never the gap).
  Coordinates are expressed in the frame of the observed joints (centroid removed,
  rotated onto their mean training pose by Kabsch) and centred on the training mean
  (the "scaled to the same level in advance" of Section III-A), so training takes
  recorded elsewhere in the room, or facing another way, still apply.
* **Boundary correction** (not in the paper, ``boundary_correction=True``): the
  estimate's error on the observed samples next to each gap is interpolated across
  the gap and removed, so fills join the observed trajectory without a step. The
  probe's estimate uses only partners also observed at the gap frame next to it (the
  gap's own model; with a whole limb missing the probe used to take the limb's other
  joints as partners). Optionally (``trust_kappa``, :func:`shrink_untrusted`) a
  gap's fill is shrunk toward linear interpolation when those end residuals are large
  against its departure from linear; streaming fills can be kept within a joint's
  recent range of motion of hold/linear (:func:`streamfix.core.excursion.limit_excursion`).
* **Plausibility projection** (not in the paper, optional,
  :func:`project_pair_distances`): filled markers are moved so rigid marker pairs
  keep the distance range observed where both are visible.
* **Weights of Eq. (13)**: ``W = diag(w_l)``, ``w_l = exp(-d_l / tau)`` with ``d_l`` the
  distance (frames) of present frame ``l`` to the nearest missing frame; ``tau`` is
  chosen from a small grid by minimising Eq. (13)'s prediction error of the removed
  part over the training samples.
* The printed Eq. (3) and Eq. (16) have typos (non-conforming ``U^T``; ``W`` missing in
  the second factor); the code uses the normal equations of Eq. (2) and Eq. (14).

Why local templates are the default: on the CMU marker takes (100-frame gaps) they filled
closer than the paper's whole-frame template, and the Eq. (8) layout (temporal only) did
no better than cubic spline when this was chosen; Eq. (8) is kept as derived
(``layout="pieces"``). ``benchmarks/bench_pca.py`` measures the default's fills.

All functions are pure: arrays in, arrays out. Positions ``(T, J, 3)`` metres, NaN =
missing, observed masks ``(T, J)`` bool. Filled values never replace observed ones.
"""
from __future__ import annotations

import numpy as np

from .pca_boundary import residual_field, shrink_untrusted
from .pca_normalise import normalise_frames
from .pca_pieces import fill_gaps_pieces
# the shared ground, the matrix estimators, the blackout estimate and the rigid pairs live
# in their own modules; their public names stay importable from here
from .pca_blackouts import blackout_weights, eq16_basis, eq16_estimate, fill_blackouts
from .pca_estimators import _eq4_from_grams, eq4_estimate, eq8_estimate
from .pca_training import DEFAULT_ENERGY, TrainingSet, _as_training, _observed_mask, choose_rank
from .rigid_pairs import (
    estimate_rigid_pairs,
    pair_distance_plausibility,
    pair_distance_ranges,
    pair_distances,
    project_pair_distances,
)

__all__ = [
    "DEFAULT_ENERGY",
    "choose_rank",
    "eq4_estimate",
    "eq8_estimate",
    "eq16_estimate",
    "eq16_basis",
    "blackout_weights",
    "fill_gaps",
    "fill_blackouts",
    "estimate_rigid_pairs",
    "pair_distance_ranges",
    "pair_distance_plausibility",
    "project_pair_distances",
    "TrainingSet",
    "DEFAULT_PARTNERS",
    "shrink_untrusted",
]


DEFAULT_PARTNERS = (3, 6)
"""Local templates: each missing joint is predicted from this many observed joints whose
distance to it varies least in training; with several candidates, each joint takes
the count whose estimates best match its observed samples within
``validation_frames`` of its gaps (None = every observed joint, the paper's
whole-matrix template)."""


# --------------------------------------------------------------------------- gaps: Eq. (4)
def _pattern_groups(obs: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique observed patterns among ``rows`` and, per row, its pattern index."""
    pats, inv = np.unique(obs[rows], axis=0, return_inverse=True)
    return pats, inv.ravel()


def _select_predictors(obs_pat: np.ndarray, tgt: np.ndarray, tr_obs: np.ndarray, min_frames: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Observed joints to use and the training frames where they and the missing ones exist.

    Starts from the joints missing in the pattern (the targets), adds the pattern's
    observed joints in order of their availability in training and stops before the
    usable training frames drop under ``min_frames``. Returns (predictor joints, rows).
    """
    rows = tr_obs[:, tgt].all(axis=1)
    cand = np.flatnonzero(obs_pat)
    if rows.sum() == 0 or cand.size == 0:
        return cand[:0], rows
    full = rows & tr_obs[:, cand].all(axis=1)
    if full.sum() >= min_frames:
        return cand, full
    order = cand[np.argsort(-tr_obs[rows][:, cand].sum(axis=0), kind="stable")]
    keep = []
    cur = rows.copy()
    for j in order:  # greedy over joints (not frames): at most J boolean passes
        nxt = cur & tr_obs[:, j]
        if nxt.sum() < min_frames:
            continue
        keep.append(j)
        cur = nxt
    return np.array(sorted(keep), dtype=np.intp), cur


def _fill_pattern(
    x: np.ndarray, obs_pat: np.ndarray, tgt: np.ndarray, frames: np.ndarray, ctx_frames: np.ndarray,
    tr: np.ndarray, tr_obs: np.ndarray, piece_frames: int, energy: float, r_max: int | None,
    min_train_frames: int, rotate: bool = True, max_train_frames: int = 1500,
) -> np.ndarray | None:
    """Eq. (1)-(4) for one template: joints ``tgt`` missing, ``obs_pat`` observed (the
    matrix holds only these joints) in ``frames``; ``ctx_frames``: the nearby frames where
    ``obs_pat`` is observed, sorted, ``frames`` among them. Returns ``(len(frames), n_tgt, 3)``
    or None."""
    miss_j = np.flatnonzero(tgt)
    pred_j, rows = _select_predictors(obs_pat, tgt, tr_obs, min_train_frames)
    if pred_j.size == 0 or rows.sum() < min_train_frames:
        return None
    joints = np.concatenate([pred_j, miss_j])
    n_pred = pred_j.size
    # "scaled to the same level": coordinates in the frame of the observed joints
    # (centroid removed and, with ``rotate``, rotated onto a reference pose)
    rows = np.flatnonzero(rows)
    rows = rows[:: max(rows.size // max_train_frames, 1)]   # 120 Hz frames are redundant
    Yl, _, _, ref = normalise_frames(tr[rows][:, joints], n_pred, None, rotate)
    Y = Yl.reshape(Yl.shape[0], -1)
    mu = Y.mean(axis=0)
    Y = Y - mu
    n = Y.shape[1]
    o = 3 * n_pred                                           # observed coordinates come first
    # pieces A_i of the long sequence (Eq. 1); the template zeroes the missing columns
    K = max(Y.shape[0] // piece_frames, 1)
    A = Y[: K * piece_frames].reshape(K, -1, n) if Y.shape[0] >= piece_frames else Y[None]
    G = np.swapaxes(A, 1, 2) @ A                             # A_i^T A_i
    G0 = np.zeros_like(G)
    G0[:, :o, :o] = G[:, :o, :o]                             # A_i^(0)T A_i^(0)
    C0 = np.zeros_like(G)
    C0[:, :o, :] = G[:, :o, :]                               # A_i^(0)T A_i
    lam = np.linalg.eigvalsh(G.sum(axis=0))
    r = choose_rank(lam, energy, r_max)
    r0 = min(r, max(o - (6 if rotate else 3), 1))            # normalisation removes 3 (6) dof
    r = max(r, r0)

    def _b(rows_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        Zl, cen, R, _ = normalise_frames(x[rows_idx][:, joints], n_pred, ref, rotate)
        Z = Zl.reshape(Zl.shape[0], -1) - mu
        Z[:, o:] = 0.0                                       # the template
        return Z, cen, R

    # B^(0): this template's frames; its eigenbasis from them plus nearby frames where
    # the same joints are observed (a few frames alone do not span r directions). The
    # template's frames are among those (its joints are observed there): normalised once
    Bctx, cen_ctx, R_ctx = _b(ctx_frames)
    at = np.searchsorted(ctx_frames, frames)
    B0, cen, R = Bctx[at], cen_ctx[at], R_ctx[at]
    GB0 = Bctx.T @ Bctx
    GB0[o:, :] = 0.0
    GB0[:, o:] = 0.0
    U, UB0, T = _eq4_from_grams(G, C0, G0, GB0, r, r0)
    UB0[o:] = 0.0
    Bstar = B0 @ UB0 @ T @ U.T + mu                          # Eq. (4)
    local = Bstar[:, o:].reshape(len(frames), miss_j.size, 3)
    out = local @ np.swapaxes(R, 1, 2) + cen[:, None, :]     # back to room coordinates
    return out


def fill_gaps(
    positions: np.ndarray,
    observed: np.ndarray | None,
    training,
    *,
    energy: float = DEFAULT_ENERGY,
    r_max: int | None = 60,
    piece_frames: int = 240,
    context_frames: int = 240,
    min_observed_joints: int = 3,
    min_train_frames: int | None = None,
    max_train_frames: int = 1500,
    layout: str | None = None,
    rotate: bool = True,
    boundary_correction: bool = True,
    n_partners: int | tuple[int, ...] | None = DEFAULT_PARTNERS,
    validation_frames: int = 30,
    trust_kappa: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fill joints missing in frames where at least ``min_observed_joints`` are observed.

    ``positions`` ``(T, J, 3)`` metres (NaN = missing); ``observed`` ``(T, J)`` bool or
    None (finite = observed); ``training``: a :class:`TrainingSet`, an array
    ``(T_k, J, 3)`` or a list of them (same joint order). ``layout`` overrides the
    training set's (``"sequence"`` -> Eq. 4 per missing-joint template;
    ``"pieces"`` -> Eq. 8 on windows of ``context_frames`` frames).

    ``boundary_correction`` (not in the paper): the same template is also applied to
    the observed sample just before and just after each gap; the estimate's error
    there is interpolated linearly across the gap and removed, so filled
    trajectories join the observed ones without a step. ``trust_kappa`` (local
    templates with boundary correction; None = off): each gap's fill is shrunk toward
    linear interpolation by its end residuals (:func:`shrink_untrusted`). Returns
    ``(filled, filled_mask)``; observed samples are returned bit-for-bit.
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = _observed_mask(x, observed)
    out = x.copy()
    out[~obs] = np.nan
    filled = np.zeros_like(obs)
    ts = _as_training(training, x.shape[1])
    layout = layout or ts.layout
    enough = obs.sum(axis=1) >= min_observed_joints
    rows = np.flatnonzero((~obs).any(axis=1) & enough)
    if rows.size == 0:
        return out, filled
    if layout == "pieces":
        return fill_gaps_pieces(x, obs, ts, rows, energy=energy, r_max=r_max, window=context_frames)
    tr = ts.frames
    tr_obs = ts.observed
    T_len, J, _ = x.shape
    need = ~obs & enough[:, None]                            # samples this function fills
    min_frames = min_train_frames or max(2 * 3 * J, 100)
    # probes: observed samples next to a gap (for the boundary correction)
    probe = np.zeros_like(need)
    if boundary_correction:
        probe[:-1] |= need[1:]
        probe[1:] |= need[:-1]
        probe &= obs & enough[:, None]
    # queries: (frame, joint or -1 for "all targets", is-probe, predictors, targets)
    if n_partners is None:
        # the paper's template: every observed joint predicts every missing one
        pt, pj = np.nonzero(probe)
        q_t = np.concatenate([rows, pt])
        q_j = np.concatenate([np.full(rows.size, -1), pj])
        q_pred = np.concatenate([obs[rows], obs[pt]])
        q_pred[np.arange(rows.size, q_t.size), pj] = False
        q_tgt = ~q_pred
        ok = q_pred.sum(axis=1) >= min_observed_joints
    else:
        return _fill_local(x, obs, need, probe, tr, tr_obs, enough, n_partners, min_observed_joints,
                           dict(piece_frames=piece_frames, energy=energy, r_max=r_max, rotate=rotate,
                                max_train_frames=max_train_frames, context_frames=context_frames),
                           min_train_frames, boundary_correction, validation_frames, trust_kappa)
    q_probe = probe[q_t, np.maximum(q_j, 0)] & (q_j >= 0)
    q_t, q_j, q_probe, q_pred, q_tgt = q_t[ok], q_j[ok], q_probe[ok], q_pred[ok], q_tgt[ok]
    keys, inv = np.unique(np.hstack([q_pred, q_tgt]), axis=0, return_inverse=True)
    inv = inv.ravel()
    resid = np.full(x.shape, np.nan)
    for p in range(keys.shape[0]):  # one template per (observed, missing) joint pattern
        sel = np.flatnonzero(inv == p)
        sel = sel[np.argsort(q_t[sel], kind="stable")]
        frames, qj, qp = q_t[sel], q_j[sel], q_probe[sel]
        pat, tgt = keys[p, :J], keys[p, J:]
        # context: frames near this template's frames where its observed joints are all seen
        lo = max(frames[0] - context_frames // 2, 0)
        hi = min(frames[-1] + context_frames // 2 + 1, T_len)
        near = np.arange(lo, hi)
        near = near[obs[near][:, pat].all(axis=1)]
        est = _fill_pattern(x, pat, tgt, frames, near, tr, tr_obs, piece_frames, energy, r_max, min_frames,
                            rotate, max_train_frames)
        if est is None:
            continue
        miss_j = np.flatnonzero(tgt)
        g = ~qp & (qj < 0)                                   # gap rows, all targets
        if g.any():
            fr = frames[g]
            out[fr[:, None], miss_j[None, :]] = est[g]
            filled[fr[:, None], miss_j[None, :]] = True
        col = np.searchsorted(miss_j, np.maximum(qj, 0))
        one = ~qp & (qj >= 0)                                # gap samples, one target
        if one.any():
            out[frames[one], qj[one]] = est[one, col[one]]
            filled[frames[one], qj[one]] = True
        if qp.any():                                         # probe residuals e = x - x_hat
            resid[frames[qp], qj[qp]] = x[frames[qp], qj[qp]] - est[qp, col[qp]]
    filled &= need
    if boundary_correction and filled.any():
        out = out + residual_field(resid, obs, filled)
    out[obs] = x[obs]
    return out, filled


def _template_groups(predictors: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Queries with the same template: ``predictors`` ``(N, J)`` bool (the partners observed) and
    ``target`` ``(N,)`` (the joint estimated). Returns ``(first, inverse)``: each group's first
    query and each query's group. Each row is packed into bytes and the rows compared as such:
    ``np.unique(axis=0)`` compares them element by element, which dominated fills with many gap
    patterns. The groups' order is not ``np.unique(axis=0)``'s; the templates are independent."""
    packed = np.concatenate([np.packbits(predictors, axis=1),
                             np.asarray(target, dtype=np.int64)[:, None].view(np.uint8)], axis=1)
    rows = np.ascontiguousarray(packed).view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    return first, inverse.ravel()


def _local_estimates(x, obs, qt, qj, tr, tr_obs, rank, k, min_observed_joints, kw, min_frames, optional=None,
                     pt=None):
    """Eq. (1)-(4) estimates ``(N, 3)`` of joint ``qj`` at frame ``qt`` from its ``k`` most
    rigid partners observed there (NaN where no estimate). ``optional`` queries are
    answered only when their template is needed by a required one anyway. ``pt``
    (frames, default ``qt``): partners must also be observed there (a boundary probe
    uses the partners of the gap frame next to it, so its residual is the gap model's)."""
    T_len, J, _ = x.shape
    est_all = np.full((qt.size, 3), np.nan)
    avail = obs[qt[:, None], rank[qj]].copy()                # (N, J-1) partner observed?
    if pt is not None:
        avail &= obs[pt[:, None], rank[qj]]
    avail &= np.cumsum(avail, axis=1) <= k
    q_pred = np.zeros((qt.size, J), dtype=bool)
    q_pred[np.repeat(np.arange(qt.size), J - 1), rank[qj].ravel()] = avail.ravel()
    ok = np.flatnonzero(q_pred.sum(axis=1) >= min(min_observed_joints, k))
    if ok.size == 0:
        return est_all
    first, inv = _template_groups(q_pred[ok], qj[ok])
    rep = ok[first]  # each template's first query: its partners and target
    if optional is not None:
        needed = np.zeros(len(first), dtype=bool)
        needed[inv[~optional[ok]]] = True
        keep = needed[inv]
        ok, inv = ok[keep], inv[keep]
    ctx = kw["context_frames"]
    # one template per (target joint, observed partners); each one's queries in their order in
    # ``ok``, from one stable sort rather than a scan of every query per template
    order = np.argsort(inv, kind="stable")
    groups, starts = np.unique(inv[order], return_index=True)
    for p, members in zip(groups, np.split(order, starts[1:])):
        sel = ok[members]
        sel = sel[np.argsort(qt[sel], kind="stable")]
        frames = qt[sel]
        pat = q_pred[rep[p]]
        tgt = np.zeros(J, dtype=bool)
        tgt[qj[rep[p]]] = True
        lo, hi = max(frames[0] - ctx // 2, 0), min(frames[-1] + ctx // 2 + 1, T_len)
        near = np.arange(lo, hi)
        near = near[obs[near][:, pat].all(axis=1)]
        est = _fill_pattern(x, pat, tgt, frames, near, tr, tr_obs, kw["piece_frames"], kw["energy"], kw["r_max"],
                            min_frames, kw["rotate"], kw["max_train_frames"])
        if est is not None:
            est_all[sel] = est[:, 0]
    return est_all


def _fill_local(x, obs, need, probe, tr, tr_obs, enough, n_partners, min_observed_joints, kw, min_train_frames,
                boundary_correction, validation_frames, trust_kappa=None):
    """Local templates; with several ``n_partners`` candidates, each joint takes the one
    whose estimates of its observed samples within ``validation_frames`` of its gaps
    are closest to the observations (a choice made on observed data only)."""
    T_len, J, _ = x.shape
    cands = (n_partners,) if np.isscalar(n_partners) else tuple(n_partners)
    rank = _partner_ranking(tr, tr_obs)                      # (J, J-1)
    val = np.zeros_like(need)
    if len(cands) > 1 and validation_frames > 0:
        c = np.concatenate([np.zeros((1, J), dtype=np.int64), np.cumsum(need, axis=0)])
        idx = np.arange(T_len)
        near = (c[np.minimum(idx + validation_frames + 1, T_len)] - c[np.maximum(idx - validation_frames, 0)]) > 0
        val = near & obs & enough[:, None]
    qt, qj = np.nonzero(need | probe | val)
    # a probe's partners are those observed at the gap frame next to it as well
    pt = qt.copy()
    isp = probe[qt, qj] & ~need[qt, qj]
    nxt_gap = isp & (qt + 1 < T_len) & need[np.minimum(qt + 1, T_len - 1), qj]
    prv_gap = isp & ~nxt_gap & (qt >= 1) & need[np.maximum(qt - 1, 0), qj]
    pt[nxt_gap] += 1
    pt[prv_gap] -= 1
    ests = []
    for k in cands:
        mf = min_train_frames or max(2 * 3 * (k + 1), 100)
        ests.append(_local_estimates(x, obs, qt, qj, tr, tr_obs, rank, int(k), min_observed_joints, kw, mf,
                                     optional=val[qt, qj] & ~need[qt, qj] & ~probe[qt, qj], pt=pt))
    ests = np.stack(ests)                                    # (C, N, 3)
    choice = np.zeros(qt.size, dtype=np.intp)
    if len(cands) > 1:
        isval = val[qt, qj]
        err = np.linalg.norm(ests - x[qt, qj][None], axis=2)  # (C, N)
        err = np.where(isval[None] & np.isfinite(err), err, 0.0)
        cnt = np.zeros((len(cands), J))
        tot = np.zeros((len(cands), J))
        for ci in range(len(cands)):                          # loop over candidates only
            np.add.at(tot[ci], qj, err[ci])
            np.add.at(cnt[ci], qj, isval & np.isfinite(ests[ci]).all(axis=1))
        score = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.inf)
        score[:, np.all(~np.isfinite(score), axis=0)] = 0.0   # no validation: first candidate
        best_j = np.argmin(score, axis=0)                     # (J,)
        choice = best_j[qj]
        # a chosen candidate without an estimate falls back to any candidate that has one
        chosen = ests[choice, np.arange(qt.size)]
        miss = ~np.isfinite(chosen).all(axis=1)
        if miss.any():
            anyok = np.isfinite(ests).all(axis=2)             # (C, N)
            choice[miss] = np.argmax(anyok[:, miss], axis=0)
    est = ests[choice, np.arange(qt.size)]
    have = np.isfinite(est).all(axis=1)
    out = x.copy()
    out[~obs] = np.nan
    filled = np.zeros_like(obs)
    g = need[qt, qj] & have
    out[qt[g], qj[g]] = est[g]
    filled[qt[g], qj[g]] = True
    resid = np.full(x.shape, np.nan)
    pr = probe[qt, qj] & have
    resid[qt[pr], qj[pr]] = x[qt[pr], qj[pr]] - est[pr]
    if boundary_correction and filled.any():
        out = out + residual_field(resid, obs, filled)
        if trust_kappa is not None:
            out = shrink_untrusted(out, obs, filled, resid, trust_kappa)
    out[obs] = x[obs]
    return out, filled


def _partner_ranking(tr: np.ndarray, tr_obs: np.ndarray, min_common: float = 0.1) -> np.ndarray:
    """For each joint, the other joints ordered by how little their distance to it varies
    in training (std, metres, over frames where both are seen). ``(J, J-1)`` indices."""
    J = tr.shape[1]
    sub = slice(None, None, max(tr.shape[0] // 4000, 1))
    frames = tr[sub]
    o = np.ascontiguousarray(tr_obs[sub].T)                # (J, T)
    ia, ib = np.triu_indices(J, 1)
    both = o[ia] & o[ib]                                     # (pairs, T)
    d = pair_distances(frames, ia, ib).T                     # (pairs, T), C-contiguous
    cnt = both.sum(axis=1)
    c = np.maximum(cnt, 1)
    mean = (d * both).sum(axis=1) / c
    sd = np.sqrt(((d - mean[:, None]) ** 2 * both).sum(axis=1) / c)
    sd = np.where(cnt >= max(min_common * frames.shape[0], 10), sd, 1e6 - cnt)  # rarely seen: last
    S = np.full((J, J), np.inf)
    S[ia, ib] = sd
    S[ib, ia] = sd
    return np.argsort(S, axis=1, kind="stable")[:, : J - 1]
