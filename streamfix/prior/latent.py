"""Latent-space optimisation D(z*) (Lohit et al., Eq. 1) with onnxruntime and numpy only.

    z* = argmin_z || Y - A D(z) ||_2^2,      X^ = D(z*)                          (Eq. 1)

``A`` keeps the observed joint-frames. We solve it by **Levenberg-Marquardt** on
the unknowns (z, c), where ``c`` is a constant 3-D translation added to D(z) (it
absorbs the error of the root estimate when the root joint is not observed, see
``streamfix.prior.normalize``): with residual r = A (D(z) + c - Y) and Jacobian
Jr = A [dD/dz, dD/dc], each step solves

    (Jr^T Jr + lambda diag(Jr^T Jr) + eps I) delta = -Jr^T r

The exact dD/dz comes from the exported ``decoder_jacobian`` graph: one batched
onnxruntime call per iteration returns D(z), the residual, its squared norm and the
blocks of Jr^T Jr and Jr^T r for every window of the batch (no matrix products in
numpy: a multi-threaded BLAS stalls on a busy machine).
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
    out = np.array(decoded, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool)
    if tol_m <= 0:
        out[obs] = observed_pos[obs]
        return out
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
    each, ~20x cheaper than a Jacobian call), which bounds the cost of a window.
    """
    window, observed, single = prior.as_batch(window, observed, "fit_latent")
    y, obs, norms = prior.normalise(window, observed)
    b = y.shape[0]
    n_lat = prior.latent_size
    z_start = prior.encode(y, obs).astype(np.float64) if z0 is None else np.asarray(z0, np.float64).reshape(b, n_lat)

    w = np.repeat(obs.reshape(b, -1), 3, axis=1).astype(np.float64)  # (B, N) observed coordinates of A
    yv = y.reshape(b, -1)
    n_obs = np.maximum(w.sum(axis=1), 1.0)
    eye = np.eye(n_lat + 3)
    reg = np.zeros(n_lat + 3)
    reg[:n_lat] = latent_reg

    n_par = n_lat + 3
    w32 = w.astype(np.float32)
    tj = y.shape[1] * y.shape[2]
    h_cc = w.reshape(b, tj, 3).sum(axis=1)  # (B, 3): d/dc block of Jr^T Jr is diagonal (observed count per axis)

    y32 = yv.astype(np.float32)

    def evaluate_chord(z: np.ndarray, c: np.ndarray, h: np.ndarray, jw: np.ndarray):
        # D(z) alone; the step's normal equations keep the Jacobian rows jw (B, L, N) of the last accepted point
        x = prior.decode(z).astype(np.float64)
        xv = (x.reshape(b, -1, 3) + c[:, None, :]).reshape(b, -1)
        r = w * (xv - yv)
        dz = z - z_start
        cost = (r * r).sum(axis=1) + latent_reg * (dz * dz).sum(axis=1)
        g = np.empty((b, n_par, 1))
        g[:, :n_lat, 0] = np.einsum("bln,bn->bl", jw, r) + latent_reg * dz
        g[:, n_lat:, 0] = r.reshape(b, tj, 3).sum(axis=1)
        return x, xv, cost, h, g, jw

    def evaluate(z: np.ndarray, c: np.ndarray):
        # one onnxruntime call gives D(z), r, ||r||^2 and the blocks of Jr^T Jr and Jr^T r
        ne = prior.normal_equations(z, w32, y32, c, with_jacobian=jacobian_steps is not None)
        r = ne["r"].astype(np.float64)
        xv = (ne["x"].reshape(b, -1, 3).astype(np.float64) + c[:, None, :]).reshape(b, -1)
        dz = z - z_start
        cost = ne["cost"].astype(np.float64) + latent_reg * (dz * dz).sum(axis=1)
        h = np.zeros((b, n_par, n_par))
        h[:, :n_lat, :n_lat] = ne["gram"]
        h[:, :n_lat, n_lat:] = ne["h_zc"]
        h[:, n_lat:, :n_lat] = ne["h_zc"].transpose(0, 2, 1)
        h[:, n_lat:, n_lat:] = h_cc[:, :, None] * np.eye(3)[None]
        g = np.empty((b, n_par, 1))
        g[:, :n_lat] = ne["jtr"]
        g[:, n_lat:, 0] = r.reshape(b, tj, 3).sum(axis=1)
        g[:, :n_lat, 0] += latent_reg * dz
        h += np.diag(reg)[None]
        jw = ne["jac"] * w32[:, None, :] if "jac" in ne else None
        return ne["x"], xv, cost, h, g, jw

    z = z_start.copy()
    c = np.zeros((b, 3))
    x, xv, cost, h, g, jw = evaluate(z, c)
    initial_cost = cost.copy()
    best = (z.copy(), c.copy(), xv.copy(), cost.copy(), h, g, jw)
    lam = np.full(b, float(damping))
    active = np.ones(b, dtype=bool)
    iterations = 0
    for _ in range(max_iter):
        if not active.any():
            break
        bz, bc, bxv, bcost, bh, bg, bjw = best
        diag = np.einsum("bii->bi", bh)
        lhs = bh + lam[:, None, None] * (diag[:, :, None] * eye[None]) + 1e-9 * eye[None]
        delta = -np.linalg.solve(lhs, bg)[..., 0]  # (B, L+3)
        delta[~active] = 0.0
        z_try = bz + delta[:, :n_lat]
        c_try = bc + delta[:, n_lat:]
        if jacobian_steps is None or iterations < jacobian_steps:
            x, xv, cost, h, g, jw = evaluate(z_try, c_try)
        else:
            x, xv, cost, h, g, jw = evaluate_chord(z_try, c_try, bh, bjw)
        iterations += 1
        better = (cost < bcost) & active
        gain = np.where(better, (bcost - cost) / np.maximum(bcost, 1e-30), 0.0)
        lam = np.where(better, lam / 3.0, lam * 4.0)
        upd = better[:, None]
        best = (
            np.where(upd, z_try, bz),
            np.where(upd, c_try, bc),
            np.where(upd, xv, bxv),
            np.where(better, cost, bcost),
            np.where(better[:, None, None], h, bh),
            np.where(better[:, None, None], g, bg),
            jw if jw is None or jw is bjw else np.where(better[:, None, None], jw, bjw),
        )
        active &= ~(better & (gain < rel_tol)) & (lam < 1e8)
    z, c, xv, cost = best[0], best[1], best[2], best[3]

    scales = np.array([n.scale for n in norms])
    decoded = np.stack([denormalise(xv[i].reshape(y.shape[1:]), norms[i]) for i in range(b)])
    positions = clamp_to_observed(decoded, np.nan_to_num(window), obs, fit_tol_m)
    data_cost = np.maximum(cost - latent_reg * ((z - z_start) ** 2).sum(axis=1), 0.0)
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
