"""Properties of the Yang et al. (2019) solver: wavelet operator, isometry, ADM-ALM.

Real motion: CMU 131_01 (120 Hz, 31 joints), treated as ground truth and corrupted here.
"""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core.alm import SolverParams, SolverResult, SolverState, default_rho0, solve
from streamfix.core.isometry import (
    bone_lengths_per_frame,
    estimate_bone_lengths,
    gauss_newton_step,
    isometry_jacobian,
    isometry_residual,
)
from streamfix.core.wavelets import TemporalWavelet, detail_mask, wavelet_matrix
from streamfix.io.bvh import read_bvh
from streamfix.skeletons import MEDIAPIPE_POSE


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def cmu(shared_data):
    motion = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh")
    assert motion.rate_hz == pytest.approx(120.0, rel=1e-3)
    return motion.positions, motion.skeleton.bone_array


@pytest.fixture(scope="module")
def clip(cmu):
    """120 frames (1 s) of walking: the window size tests use."""
    positions, bones = cmu
    return positions[300:420].copy(), bones


def corrupt(x: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """The paper's protocol: uniform [-0.25, 0.25] m noise on a fraction of scalar entries."""
    rng = np.random.default_rng(seed)
    mask = rng.random(x.shape) < fraction
    out = x.copy()
    out[mask] += rng.uniform(-0.25, 0.25, int(mask.sum()))
    return out


def aje(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b, axis=-1).mean())


# --------------------------------------------------------------------------- wavelets
@pytest.mark.parametrize("n_frames", [4, 5, 6, 7, 33, 64, 130, 600])
@pytest.mark.parametrize("wavelet", ["db2", "db10"])
def test_wavelet_is_orthogonal_for_any_length(n_frames, wavelet):
    W = wavelet_matrix(n_frames, wavelet, 2)
    eye = np.eye(n_frames)
    assert np.abs(W.T @ W - eye).max() < 1e-12
    assert np.abs(W @ W.T - eye).max() < 1e-12


@pytest.mark.parametrize("n_frames", [37, 600, 1030])  # dense, sparse and pywt paths
def test_wavelet_operator_matches_matrix_and_inverts(n_frames):
    rng = np.random.default_rng(0)
    x = rng.standard_normal((n_frames, 7, 3))
    op = TemporalWavelet(n_frames, "db10", 2)
    W = wavelet_matrix(n_frames, "db10", 2)
    c = op.forward(x)
    assert np.allclose(c.reshape(n_frames, -1), W @ x.reshape(n_frames, -1), atol=1e-12)
    assert np.allclose(op.inverse(c), x, atol=1e-12)
    assert np.linalg.norm(c) == pytest.approx(np.linalg.norm(x), rel=1e-12)  # Parseval


def test_detail_coefficients_of_a_constant_vanish():
    n_frames = 66
    mask = detail_mask(n_frames, 2)
    # 2 pass-through frames + 64/4 approximation coefficients
    assert (~mask).sum() == 2 + 16
    c = TemporalWavelet(n_frames, "db10", 2).forward(np.full((n_frames, 1), 3.0))
    assert np.abs(c[mask]).max() < 1e-10
    assert np.abs(c[~mask]).max() > 1.0


def test_wavelet_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 4 frames"):
        TemporalWavelet(3, "db10", 2)
    with pytest.raises(ValueError, match="not orthogonal"):
        TemporalWavelet(64, "bior4.4", 2)
    with pytest.raises(ValueError, match="expected 64 frames"):
        TemporalWavelet(64).forward(np.zeros((63, 3)))


# --------------------------------------------------------------------------- isometry
def _chain(n_frames: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    bones = np.array([[0, 1], [1, 2], [2, 3], [1, 4]])
    pos = rng.standard_normal((n_frames, 5, 3)) * 0.3
    lengths = np.array([0.3, 0.25, 0.2, 0.35])
    return pos, bones, lengths


def test_jacobian_matches_finite_differences():
    pos, bones, lengths = _chain(2, 0)
    jac = isometry_jacobian(pos, bones)  # (T, B, 3S)
    eps = 1e-6
    flat = pos.reshape(2, -1)
    for k in range(flat.shape[1]):
        dp = flat.copy()
        dp[:, k] += eps
        dm = flat.copy()
        dm[:, k] -= eps
        fd = (isometry_residual(dp.reshape(pos.shape), bones, lengths)
              - isometry_residual(dm.reshape(pos.shape), bones, lengths)) / (2 * eps)
        assert np.allclose(fd, jac[:, :, k], atol=1e-6)


def _mediapipe(n_frames: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bone graph with cycles (MediaPipe's connection list) and random lengths."""
    rng = np.random.default_rng(seed)
    bones = MEDIAPIPE_POSE.bone_array
    pos = rng.standard_normal((n_frames, MEDIAPIPE_POSE.n_joints, 3)) * 0.3
    return pos, bones, rng.uniform(0.05, 0.4, len(bones))


@pytest.mark.parametrize("rho2,gamma,case", [(0.05, 100.0, _chain), (3.0, 1.0, _chain), (0.05, 100.0, _mediapipe)])
def test_batched_gauss_newton_matches_dense_reference(rho2, gamma, case):
    N, bones, lengths = case(4, 1)
    rng = np.random.default_rng(2)
    A = N + 0.05 * rng.standard_normal(N.shape)
    Z2 = 0.1 * rng.standard_normal(N.shape)
    got = gauss_newton_step(N, A, Z2, rho2, gamma, bones, lengths)
    # Eq. (20) with the full (non-batched) 3TS x 3TS system
    n_frames, n_joints, _ = N.shape
    blocks = isometry_jacobian(N, bones)
    J = np.zeros((n_frames * len(bones), n_frames * 3 * n_joints))
    for t in range(n_frames):
        J[t * len(bones):(t + 1) * len(bones), t * 3 * n_joints:(t + 1) * 3 * n_joints] = blocks[t]
    F = isometry_residual(N, bones, lengths).ravel()
    rhs = -Z2.ravel() - rho2 * (N - A).ravel() - gamma * J.T @ F
    delta = np.linalg.solve(gamma * J.T @ J + rho2 * np.eye(J.shape[1]), rhs)
    assert np.allclose(got, N + delta.reshape(N.shape), atol=1e-10)


def test_gauss_newton_reduces_isometry_energy():
    N, bones, lengths = _chain(6, 3)
    before = np.sum(isometry_residual(N, bones, lengths) ** 2)
    zero = np.zeros_like(N)
    after_n = gauss_newton_step(N, N, zero, 1e-3, 100.0, bones, lengths)
    after = np.sum(isometry_residual(after_n, bones, lengths) ** 2)
    assert after < 0.5 * before


def test_bone_length_estimate_is_robust_to_corruption(clip):
    gt, bones = clip
    truth = bone_lengths_per_frame(gt, bones)[0]
    noisy = corrupt(gt, 0.2, seed=0)  # ~74 % of frames have a corrupted bone end
    mode = estimate_bone_lengths(noisy, bones)
    median = estimate_bone_lengths(noisy, bones, method="median")
    assert np.abs(mode - truth).max() < 0.005
    assert np.abs(median - truth).mean() > 5 * np.abs(mode - truth).mean()


def test_bone_length_estimate_uses_only_observed_frames(clip):
    gt, bones = clip
    truth = bone_lengths_per_frame(gt, bones)[0]
    garbage = gt.copy()
    observed = np.ones(gt.shape[:2], dtype=bool)
    observed[:80, 20] = False  # LeftWrist unobserved in 2/3 of the frames
    garbage[:80, 20] += 1.0
    est = estimate_bone_lengths(garbage, bones, observed)
    assert np.allclose(est, truth, atol=1e-9)
    never = observed.copy()
    never[:, 20] = False
    est = estimate_bone_lengths(gt, bones, never)
    touching = (bones == 20).any(axis=1)
    assert np.isnan(est[touching]).all() and np.isfinite(est[~touching]).all()


# --------------------------------------------------------------------------- solver
def test_clean_input_is_returned_nearly_unchanged(clip):
    gt, bones = clip
    res = solve(gt, None, bones)
    err = np.linalg.norm(res.positions - gt, axis=-1)
    assert res.converged
    assert err.mean() < 0.003
    assert np.median(err) < 0.0005
    # with a larger sparse-error weight nothing is mistaken for an outlier
    res = solve(gt, None, bones, params=SolverParams(lam=2.0 / np.sqrt(len(gt))))
    assert aje(res.positions, gt) < 0.0005


def test_alm_primal_residuals_go_to_zero(clip):
    gt, bones = clip
    D = corrupt(gt, 0.1, seed=1)
    res = solve(D, None, bones, params=SolverParams(tol=1e-9))
    r = res.primal_residuals
    assert res.converged and res.iterations == len(r)
    assert r[-1] < 1e-9 and r[-1] < 1e-6 * r[0]
    # the constraints of Eq. (8) hold at exit
    st = res.state
    scale = np.linalg.norm(D)
    assert np.linalg.norm(D - st.A - st.E) < 1e-8 * scale
    assert np.linalg.norm(st.N - st.A) < 1e-8 * scale
    assert np.linalg.norm(st.Ct - st.A) < 1e-8 * scale


@pytest.mark.parametrize("fraction,bound", [(0.05, 0.006), (0.10, 0.008), (0.20, 0.015)])
def test_sparse_corruption_is_removed(clip, fraction, bound):
    gt, bones = clip
    D = corrupt(gt, fraction, seed=2)
    res = solve(D, None, bones)
    assert aje(res.positions, gt) < bound < aje(D, gt)
    # the sparse error E picks up the injected noise
    injected = np.abs(D - gt) > 0.05
    assert np.mean(np.abs(res.sparse_error[injected]) > 0.02) > 0.9


def test_isometry_brings_bone_length_variation_down(clip):
    gt, bones = clip
    noisy = gt + np.random.default_rng(3).normal(0.0, 0.01, gt.shape)
    std_in = bone_lengths_per_frame(noisy, bones).std(axis=0).mean()
    stds = {}
    for mode in ("wang", "li", "yang"):
        res = solve(noisy, None, bones, params=SolverParams(mode=mode))
        stds[mode] = bone_lengths_per_frame(res.positions, bones).std(axis=0).mean()
    assert stds["li"] < 0.6 * std_in and stds["yang"] < 0.6 * std_in
    assert stds["wang"] > 0.8 * std_in  # no isometry term: no such effect


def test_modes_differ_as_expected(clip):
    gt, bones = clip
    D = corrupt(gt, 0.1, seed=4)
    true_len = bone_lengths_per_frame(gt, bones)[0]
    out = {}
    for mode in ("wang", "li", "yang"):
        a = solve(D, None, bones, true_len, params=SolverParams(mode=mode)).positions
        b = solve(D, None, bones, 1.1 * true_len, params=SolverParams(mode=mode)).positions
        out[mode] = (a, b)
    # wang ignores bone lengths entirely; li and yang pull bones toward them
    assert np.array_equal(out["wang"][0], out["wang"][1])
    for mode in ("li", "yang"):
        grown = bone_lengths_per_frame(out[mode][1], bones).mean(0) - bone_lengths_per_frame(out[mode][0], bones).mean(0)
        long_bones = true_len > 0.05
        assert np.median(grown[long_bones] / true_len[long_bones]) > 0.03
    # the wavelet term is what separates yang from li
    assert aje(out["yang"][0], out["li"][0]) > 1e-4
    # each added prior helps on this protocol (Table II ordering)
    errs = {m: aje(out[m][0], gt) for m in out}
    assert errs["yang"] < errs["li"] < errs["wang"]


def test_missing_joints_are_recovered(clip):
    gt, bones = clip
    rng = np.random.default_rng(5)
    observed = np.ones(gt.shape[:2], dtype=bool)
    for j in rng.choice(gt.shape[1], 8, replace=False):  # 8 joints lose a 12-frame run
        s = rng.integers(5, len(gt) - 17)
        observed[s:s + 12, j] = False
    D = gt.copy()
    D[~observed] = np.nan
    res = solve(D, observed, bones)
    err = np.linalg.norm(res.positions - gt, axis=-1)
    assert np.isfinite(res.positions).all()
    assert err[~observed].mean() < 0.03
    assert err[observed].mean() < 0.003
    assert np.isnan(res.sparse_error[~observed]).all()


def test_unobserved_values_are_ignored(clip):
    gt, bones = clip
    observed = np.ones(gt.shape[:2], dtype=bool)
    observed[40:60, [5, 20]] = False
    a = gt.copy()
    a[~observed] = np.nan
    b = gt.copy()
    b[~observed] = 1e3  # garbage where not observed
    ra = solve(a, observed, bones)
    rb = solve(b, observed, bones)
    assert np.allclose(ra.positions, rb.positions, atol=1e-9)


def test_warm_start_converges_in_fewer_iterations(cmu):
    positions, bones = cmu
    D = corrupt(positions[:200], 0.1, seed=6)
    n_frames, hop = 128, 16
    first = solve(D[:n_frames], None, bones)
    assert first.converged
    window = D[hop:hop + n_frames]
    cold = solve(window, None, bones)
    warm = solve(window, None, bones, state=first.state.shifted(hop))
    assert cold.converged and warm.converged
    assert warm.iterations < cold.iterations
    truth = positions[hop:hop + n_frames]
    assert aje(warm.positions, truth) < 1.3 * aje(cold.positions, truth) + 1e-3


def test_shifted_state_layout(clip):
    gt, bones = clip
    res = solve(corrupt(gt, 0.05, 7), None, bones)
    st = res.state
    sh = st.shifted(10)
    assert isinstance(sh, SolverState) and sh.fresh == 10
    for name in ("A", "E", "Ct", "N", "Z1", "Z2", "Z3t"):
        x, y = getattr(st, name), getattr(sh, name)
        assert y.shape == x.shape
        assert np.array_equal(y[:-10], x[10:])
    assert np.array_equal(sh.A[-10:], np.repeat(st.A[-1:], 10, axis=0))
    assert not np.any(sh.Z1[-10:]) and not np.any(sh.E[-10:])
    with pytest.raises(ValueError, match="hop"):
        st.shifted(len(gt) + 1)


def test_init_replaces_default_initialisation(clip):
    gt, bones = clip
    D = corrupt(gt, 0.1, seed=8)
    base = solve(D, None, bones)
    primed = solve(D, None, bones, init=gt)
    assert not np.allclose(base.positions, primed.positions)
    assert aje(primed.positions, gt) <= aje(base.positions, gt) + 5e-4


def test_result_contract_and_errors(clip):
    gt, bones = clip
    res = solve(gt[:40], np.ones((40, gt.shape[1]), bool), bones, params=SolverParams(max_iter=3))
    assert isinstance(res, SolverResult)
    assert res.positions.shape == (40, gt.shape[1], 3)
    assert res.iterations == 3 and not res.converged and len(res.primal_residuals) == 3
    with pytest.raises(ValueError, match=r"\(T, J, 3\)"):
        solve(gt[..., :2], None, bones)
    with pytest.raises(ValueError, match=r"observed must be \(T, J\) = \(120, 31\)"):
        solve(gt, np.ones((120, 30), bool), bones)
    with pytest.raises(ValueError, match=r"bone_lengths must be \(30,\)"):
        solve(gt, None, bones, bone_lengths=np.ones(3))
    with pytest.raises(ValueError, match="mode"):
        SolverParams(mode="pca")


def test_entry_weights_scale_the_sparse_penalty(clip):
    gt, bones = clip
    D = corrupt(gt, 0.1, seed=9)
    base = solve(D, None, bones)
    ones = solve(D, None, bones, weights=np.ones(gt.shape[:2]))
    assert np.array_equal(base.positions, ones.positions)
    # weight 0 = the data term does not bind there: the same ALM iterates as not
    # observing it (fixed centring, rho0, start and iteration count, since those are
    # otherwise computed from the observed entries)
    hidden = np.zeros(gt.shape[:2], dtype=bool)
    hidden[30:50, [3, 9, 26]] = True
    w = np.where(hidden, 0.0, 1.0)
    p = SolverParams(center="none", rho0=0.05, tol=0.0, max_iter=40)
    start = np.repeat(D.mean(axis=0, keepdims=True), len(D), axis=0)
    weighted = solve(D, None, bones, gt_lengths := bone_lengths_per_frame(gt, bones)[0], p, init=start, weights=w)
    masked = solve(D, ~hidden, bones, gt_lengths, p, init=start)
    assert np.allclose(weighted.positions, masked.positions, atol=1e-8)
    assert aje(weighted.positions, base.positions) > 1e-5  # and it did matter
    with pytest.raises(ValueError, match="weights must be non-negative"):
        solve(D, None, bones, weights=-np.ones(gt.shape[:2]))


def test_never_observed_joint_and_empty_window(clip):
    gt, bones = clip
    observed = np.ones(gt.shape[:2], dtype=bool)
    observed[:, 26] = False  # a joint the sensor never saw
    res = solve(gt, observed, bones)
    assert np.isfinite(res.positions).all()
    touching = (bones == 26).any(axis=1)
    assert np.isnan(res.bone_lengths[touching]).all()
    assert aje(res.positions[:, observed[0]], gt[:, observed[0]]) < 0.003
    with pytest.raises(ValueError, match="no observed joint"):
        solve(gt, np.zeros(gt.shape[:2], dtype=bool), bones)


def test_default_rho0_is_the_inexact_alm_rule(clip):
    gt, bones = clip
    rho0 = default_rho0(gt)
    centred = gt - gt.mean(axis=(0, 1))
    assert rho0 == pytest.approx(1.25 / np.linalg.norm(centred.transpose(0, 2, 1).reshape(-1, gt.shape[1]), 2))
    D = corrupt(gt, 0.1, seed=10)
    a = solve(D, None, bones, params=SolverParams(rho0=default_rho0(D) * 3.0))
    b = solve(D, None, bones, params=SolverParams(rho0_scale=3.0))
    assert np.array_equal(a.positions, b.positions)
    # the paper's rho0 = 0.5 in metre units: E swallows the signal (module docstring)
    bad = solve(D, None, bones, params=SolverParams(rho0=0.5, center="none"))
    assert aje(bad.positions, gt) > 0.5


@pytest.mark.parametrize("n_frames", [1, 2, 3, 5])
def test_very_short_windows_are_solved(clip, n_frames):
    gt, bones = clip
    res = solve(gt[:n_frames], None, bones)
    assert res.positions.shape == (n_frames, gt.shape[1], 3)
    assert np.isfinite(res.positions).all()
    assert aje(res.positions, gt[:n_frames]) < 0.01
