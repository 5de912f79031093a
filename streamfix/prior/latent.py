"""Latent-space optimisation D(z*) (Lohit et al., Eq. 1) with onnxruntime and numpy only.

    z* = argmin_z || Y - A D(z) ||_2^2,      X^ = D(z*)                          (Eq. 1)

``A`` keeps the observed joint-frames. We solve it by **Levenberg-Marquardt** on
the unknowns (z, c), where ``c`` is a constant 3-D translation added to D(z) (it
absorbs the error of the root estimate when the root joint is not observed, see
``streamfix.prior.normalize``): with residual r = A (D(z) + c - Y) and Jacobian
Jr = A [dD/dz, dD/dc], each step solves

    (Jr^T Jr + lambda diag(Jr^T Jr) + eps I) delta = -Jr^T r

dD/dz comes from the exported ``decoder_jacobian`` graph (exact, or with its tangent
products in 8-bit integers as the shipped graph: a few per cent of rounding, which steers the
step only, since a step is accepted on the float32 cost): one batched
onnxruntime call per iteration returns D(z), the residual, its squared norm and the
blocks of Jr^T Jr and Jr^T r for every window of the batch (no matrix products in
numpy: a multi-threaded BLAS stalls on a busy machine). Those blocks are summed over
every ``Prior.jacobian_frame_step``-th frame and scaled by the step (the shipped graph: every
second frame, half the cost; the residual and the cost that accepts a step use every frame).
A step is accepted if it lowers ||r||^2 (lambda /= 3), otherwise rejected (lambda *= 4)
and recomputed from the stored normal equations. The start is z(0) = E(Y), as in the
paper (Sec. 5); the paper runs 500 Adam steps, Gauss-Newton needs a handful.

**Fitting tolerance** (what "observed joints fit" means in the output): for every
observed joint-frame (t, j), the returned position X^[t, j] lies within
``fit_tol_m`` metres (Euclidean) of the observation Y[t, j]: the decoder's value is
projected onto the ball of radius ``fit_tol_m`` around Y[t, j]. With the default
``fit_tol_m = 0`` observed joints are returned exactly as observed and only
unobserved joints come from D(z*). The decoder's own fit error on the observed
joints is reported as ``fit_rms_m``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .normalize import denormalise, rot_y
from .runtime import Prior

__all__ = ["LatentFit", "fit_latent", "clamp_to_observed"]


@dataclass
class LatentFit:
    """Result of D(z*) for a batch of windows (a single window has the batch axis removed)."""

    positions: np.ndarray  # (B, T, J, 3) m, observed joints within fit_tol_m of the input
    decoded: np.ndarray  # (B, T, J, 3) m, D(z*) + c for every joint
    z: np.ndarray  # (B, L)
    translation_m: np.ndarray  # (B, 3) c in metres
    iterations: int  # LM iterations (decoder-Jacobian calls) run
    fit_rms_m: np.ndarray  # (B,) RMS of D(z*) - Y over observed coordinates, metres
    initial_rms_m: np.ndarray  # (B,) the same for z(0) = E(Y)


def clamp_to_observed(decoded: np.ndarray, observed_pos: np.ndarray, observed: np.ndarray, tol_m: float) -> np.ndarray:
    """Project each observed joint of ``decoded`` onto the ball of radius ``tol_m`` around the observation."""
    obs = np.asarray(observed, dtype=bool)
    if tol_m <= 0:
        return np.where(obs[..., None], observed_pos, decoded).astype(np.float64, copy=False)
    out = np.array(decoded, dtype=np.float64)
    d = out[obs] - observed_pos[obs]
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    factor = np.minimum(1.0, tol_m / np.maximum(n, 1e-12))
    out[obs] = observed_pos[obs] + d * factor
    return out


def fit_latent(
    prior: Prior,
    window: np.ndarray,
    observed: np.ndarray,
    *,
    max_iter: int = 6,
    rel_tol: float = 1e-4,
    fit_tol_m: float = 0.0,
    latent_reg: float = 0.0,
    z0: np.ndarray | None = None,
    damping: float = 1.0,
    jacobian_steps: int | None = None,
) -> LatentFit:
    """D(z*) for (T, J, 3) metre windows (or batches (B, T, J, 3)) with masks (T, J) / (B, T, J).

    ``max_iter`` LM iterations at most; stops early when the cost falls by less than
    ``rel_tol`` (relative). ``latent_reg`` adds ``latent_reg * ||z - z0||^2`` (0 = Eq. 1 as published).
    ``z0`` overrides the start E(Y) (e.g. the previous window's z* in a stream).
    ``damping``: initial Levenberg-Marquardt lambda (relative to diag(Jr^T Jr)).
    ``jacobian_steps``: iterations that recompute dD/dz (None = every one); later
    iterations keep the last accepted Jacobian (the chord method: one plain decoder call
    each, far cheaper than a Jacobian call), which bounds the cost of a window.
    """
    window, observed, single = prior.as_batch(window, observed, "fit_latent")
    y, obs, norms = prior.normalise(window, observed)
    b = y.shape[0]
    n_lat = prior.latent_size
    n_par = n_lat + 3
    tj = y.shape[1] * y.shape[2]
    z_start = prior.encode(y, obs).astype(np.float64) if z0 is None else np.asarray(z0, np.float64).reshape(b, n_lat)
    # float32 throughout the products (the graphs' precision); costs and the small solves in float64
    w32 = np.repeat(obs.reshape(b, -1), 3, axis=1).astype(np.float32)  # (B, N) observed coordinates of A
    y32 = y.reshape(b, -1).astype(np.float32)
    counts = obs.reshape(b, tj).sum(axis=1).astype(np.float64)  # observed joint-frames: d/dc block of Jr^T Jr
    n_obs = np.maximum(3.0 * counts, 1.0)
    diag_i = np.arange(n_par)
    chord = jacobian_steps is not None
    # the Jacobian rows themselves are needed for the gradient after a chord step, so not when the only
    # step is the first one (it uses the normal equations of the linearisation)
    keep_jacobian = chord and max_iter > max(jacobian_steps, 0) + 1
    step = prior.jacobian_frame_step  # the Jacobian rows are of every step-th frame; sums over them count step-fold

    def rows(v: np.ndarray) -> np.ndarray:
        return v.reshape(b, y.shape[1], -1)[:, ::step].reshape(b, -1) if step > 1 else v

    def linearise(z: np.ndarray, c: np.ndarray):
        # one onnxruntime call gives D(z), r, ||r||^2 and the blocks of Jr^T Jr and Jr^T r
        ne = prior.normal_equations(z, w32, y32, c, with_jacobian=keep_jacobian)
        cost = ne["cost"].astype(np.float64)
        h = np.empty((b, n_par, n_par))
        h[:, :n_lat, :n_lat] = ne["gram"]
        h[:, :n_lat, n_lat:] = ne["h_zc"]
        h[:, n_lat:, :n_lat] = ne["h_zc"].transpose(0, 2, 1)
        h[:, n_lat:, n_lat:] = counts[:, None, None] * np.eye(3)
        g = np.empty((b, n_par))
        g[:, :n_lat] = ne["jtr"][..., 0]
        g[:, n_lat:] = np.einsum("bnk->bk", ne["r"].reshape(b, tj, 3))  # (a middle-axis .sum costs more)
        if latent_reg:
            dz = z - z_start
            cost += latent_reg * (dz * dz).sum(axis=1)
            h[:, diag_i[:n_lat], diag_i[:n_lat]] += latent_reg
            g[:, :n_lat] += latent_reg * dz
        jw = ne["jac"] * rows(w32)[:, None, :] if keep_jacobian else None
        return ne["x"].reshape(b, tj, 3), cost, h, g, jw

    def chord_step(z: np.ndarray, c: np.ndarray, jw: np.ndarray):
        # D(z) alone; the normal matrix and the Jacobian rows jw (B, L, N) stay those of the last linearisation
        x = prior.decode(z).reshape(b, tj, 3)
        r = (x + c[:, None, :].astype(np.float32)).reshape(b, -1)
        r -= y32
        r *= w32
        cost = np.einsum("bn,bn->b", r, r, dtype=np.float64)
        g = np.full((b, n_par), np.nan)
        if latent_reg:
            cost += latent_reg * ((z - z_start) ** 2).sum(axis=1)
        if jw is None:  # the last step: no gradient needed (keep_jacobian)
            return x, cost, g
        g[:, :n_lat] = step * (jw @ rows(r)[:, :, None])[..., 0]  # float32 matrix-vector products
        g[:, n_lat:] = r.reshape(b, tj, 3).sum(axis=1)
        if latent_reg:
            g[:, :n_lat] += latent_reg * (z - z_start)
        return x, cost, g

    z = z_start.copy()
    c = np.zeros((b, 3))
    x, cost, h, g, jw = linearise(z, c)
    initial_cost = cost.copy()
    lam = np.full(b, float(damping))
    active = np.ones(b, dtype=bool)
    iterations = 0
    for _ in range(max_iter):
        if not active.any():
            break
        lhs = h.copy()
        lhs[:, diag_i, diag_i] = h[:, diag_i, diag_i] * (1.0 + lam[:, None]) + 1e-9  # LM: lambda diag(Jr^T Jr) added
        delta = -np.linalg.solve(lhs, g[:, :, None])[..., 0]  # (B, L+3)
        delta[~active] = 0.0
        z_try, c_try = z + delta[:, :n_lat], c + delta[:, n_lat:]
        if not chord or iterations < jacobian_steps:
            x_try, cost_try, h_try, g_try, jw_try = linearise(z_try, c_try)
        else:
            (x_try, cost_try, g_try), h_try, jw_try = chord_step(z_try, c_try, jw), h, jw
        iterations += 1
        better = (cost_try < cost) & active
        gain = np.where(better, (cost - cost_try) / np.maximum(cost, 1e-30), 0.0)
        lam = np.where(better, lam / 3.0, lam * 4.0)
        if better.all():
            z, c, x, cost, h, g, jw = z_try, c_try, x_try, cost_try, h_try, g_try, jw_try
        elif better.any():
            z, c, x, cost, g = (np.where(better.reshape((b,) + (1,) * (v.ndim - 1)), v_try, v)
                                for v, v_try in ((z, z_try), (c, c_try), (x, x_try), (cost, cost_try), (g, g_try)))
            if h_try is not h:
                h = np.where(better[:, None, None], h_try, h)
                jw = None if jw is None else np.where(better[:, None, None], jw_try, jw)
        active &= ~(better & (gain < rel_tol)) & (lam < 1e8)
    xv = (x.astype(np.float64) + c[:, None, :]).reshape(b, -1)

    scales = np.array([n.scale for n in norms])
    decoded = np.stack([denormalise(xv[i].reshape(y.shape[1:]), norms[i]) for i in range(b)])
    positions = clamp_to_observed(decoded, window, obs, fit_tol_m)  # reads the window where observed (finite) only
    data_cost = np.maximum(cost - latent_reg * ((z - z_start) ** 2).sum(axis=1), 0.0) if latent_reg else cost
    fit = LatentFit(
        positions=positions,
        decoded=decoded,
        z=z,
        translation_m=np.stack([rot_y(n.theta).T @ ci * n.scale for ci, n in zip(c, norms)]),
        iterations=iterations,
        fit_rms_m=np.sqrt(data_cost / n_obs) * scales,
        initial_rms_m=np.sqrt(initial_cost / n_obs) * scales,
    )
    if single:
        fit.positions, fit.decoded, fit.z = fit.positions[0], fit.decoded[0], fit.z[0]
        fit.translation_m, fit.fit_rms_m, fit.initial_rms_m = fit.translation_m[0], fit.fit_rms_m[0], fit.initial_rms_m[0]
    return fit
