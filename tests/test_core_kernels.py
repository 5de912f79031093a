"""The compiled kernels (streamfix.core.kernels) against their numpy references, on real recordings.

Each kernel must give its reference's values (running median: bit for bit; the local
quadratic and the bone projection: to rounding), and the window cleaner must give the
same output with the kernels as with the references (within 1e-6 m). The suite fails
rather than skips without numba: it is a base dependency.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import correlate1d

from streamfix.core import bone_projection, filters, kernels, local_poly, pipeline, robust_fit
from streamfix.core.isometry import estimate_bone_lengths
from streamfix.io import read_motion


@pytest.fixture(scope="module")
def cmu30(shared_data):
    m = read_motion(shared_data / "cmu_bvh" / "131_02.bvh")
    return m.positions[::4][:200], m.skeleton.bone_array  # 120 -> 30 Hz, 200 frames


@pytest.fixture(scope="module")
def kinect(shared_data):
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    return m.positions, m.confidence, m.skeleton.bone_array


def test_numba_is_available_and_used():
    assert kernels.HAVE_NUMBA, "numba is a base dependency: pip install numba"
    assert kernels.COMPILED, "STREAMFIX_NUMBA=0 is set: the kernels are switched off"


def _weights_with_holes(shape, seed):
    rng = np.random.default_rng(seed)
    w = rng.uniform(0, 1, size=shape) * (rng.random(shape) < 0.6)
    w[10:30, :5] = 0.0          # nothing in the window
    w[40:60, 5:10] = 0.0
    w[45, 5:10] = 0.7           # a lone sample
    w[50:52, 6] = 1.0           # two samples
    return w


@pytest.mark.parametrize("h", [2, 4, 9, 36])
def test_local_poly_kernel_matches_numpy_reference(cmu30, h):
    gt, _ = cmu30
    y = gt[:120].reshape(120, -1)
    w = _weights_with_holes(y.shape, h)
    fit, support = kernels.local_poly(y, w, h)
    ref_fit, ref_support = local_poly.local_poly_numpy(y, w, h)
    # a quadratic through >= 3 samples agrees to rounding; with 1-2 samples the fit is
    # fixed by the tiny ridge and the rounding of the sums moves it by up to ~1e-7 m
    assert np.abs(fit - ref_fit).max() < 1e-6
    samples = correlate1d((w > 0).astype(float), np.ones(2 * h + 1), axis=0, mode="constant")
    assert np.abs(fit - ref_fit)[samples >= 3].max() < 1e-10
    assert np.allclose(support, ref_support, rtol=0, atol=1e-12)


@pytest.mark.parametrize("window", [1, 2, 3, 5, 8, 17, 73])
def test_running_median_kernel_is_bit_identical(kinect, window):
    x, conf, _ = kinect
    x = np.where((conf > 0)[..., None], x, np.nan)
    x[20:40, 3] = np.nan                      # a joint missing for longer than the window
    x[:, 5] = np.nan                          # and one never seen
    got = kernels.running_median(x, window)
    ref = filters._running_median_numpy(x.copy(), window)
    assert got.shape == ref.shape
    assert np.array_equal(got, ref, equal_nan=True)
    # few channels take the sorted loop, many the branch-free one (75 here): both exact
    narrow = x[:, 3:6]
    assert narrow.shape[1] * 3 < kernels._WIDE_MEDIAN_MIN_CHANNELS < x.shape[1] * 3
    assert np.array_equal(kernels.running_median(narrow, window),
                          filters._running_median_numpy(narrow.copy(), window), equal_nan=True)
    assert np.array_equal(filters.running_median(x, window, detrend_edges=False), ref, equal_nan=True)
    assert np.array_equal(filters.running_median(x, window), filters._detrended_edges(x, ref, window), equal_nan=True)
    # the compiled edges, also beyond the windows they are dispatched for
    assert np.array_equal(kernels.detrended_edges(x, ref, window), filters._detrended_edges(x, ref, window),
                          equal_nan=True)


@pytest.mark.parametrize("window", [2, 5, 9, 19])
def test_running_median_kernel_with_ties_and_infinities(window):
    # integer samples (many ties), infinities among them and missing stretches, on 40
    # channels (the branch-free loop, which keeps empty slots as +inf)
    rng = np.random.default_rng(window)
    x = rng.integers(-3, 4, size=(300, 40)).astype(float)
    x[rng.random(x.shape) < 0.02] = np.inf
    x[rng.random(x.shape) < 0.02] = -np.inf
    x[rng.random(x.shape) < 0.2] = np.nan
    x[50:80, :7] = np.nan
    with np.errstate(invalid="ignore"):  # an even count's middle pair may be -inf and +inf: NaN in both
        ref = filters._running_median_numpy(x.copy(), window)
    assert np.array_equal(kernels.running_median(x, window), ref, equal_nan=True)


def test_running_median_kernel_on_takes_shorter_than_the_window():
    rng = np.random.default_rng(7)
    for n_frames in (1, 2, 5):
        for window in (1, 2, 5, 19):
            x = rng.normal(size=(n_frames, 20, 3))  # 60 channels: the branch-free loop
            x[rng.random(x.shape) < 0.3] = np.nan
            assert np.array_equal(kernels.running_median(x, window),
                                  filters._running_median_numpy(x.copy(), window), equal_nan=True)


def test_pbd_kernel_matches_numpy_reference(kinect):
    x, conf, bones = kinect
    x = x[:100]
    rng = np.random.default_rng(3)
    noisy = x + rng.normal(scale=0.02, size=x.shape)
    lengths = estimate_bone_lengths(x, bones)
    lengths[2] = np.nan                       # a bone without a length is left alone
    inv_mass = 1.0 / np.maximum(conf[:100], 0.25)
    got = kernels.project_bone_lengths_pbd(noisy, bones, lengths, 50, inv_mass)
    ref = bone_projection.project_bone_lengths_pbd(noisy, bones, lengths, 50, inv_mass)
    assert np.abs(got - ref).max() < 1e-12
    assert np.abs(got - noisy).max() > 1e-3   # it did move the joints


def _use_numpy_references(monkeypatch):
    """Every kernel call site of the window cleaner back on its numpy reference."""
    monkeypatch.setattr(kernels, "COMPILED", False)


@pytest.mark.parametrize("h", [2, 4, 9])
def test_robust_fit_kernel_matches_numpy_reference(kinect, monkeypatch, h):
    x, conf, _ = kinect
    x = x[:60].copy()
    rng = np.random.default_rng(h)
    spikes = rng.random(x.shape) < 0.2        # the paper protocol's corruption, heavy
    x[spikes] += rng.uniform(-0.25, 0.25, size=int(spikes.sum()))
    x[10:30, 4] = np.nan
    prior = np.where(conf[:60] >= 1.0, 1.0, np.where(conf[:60] > 0, 0.5, 0.0))
    fit, resid, support = kernels.robust_temporal_fit(x, prior, h)
    _use_numpy_references(monkeypatch)
    ref_fit, ref_resid, ref_support = robust_fit.robust_temporal_fit(x, prior, h)
    assert np.abs(fit - ref_fit).max() < 1e-6
    assert np.array_equal(np.isnan(resid), np.isnan(ref_resid))
    assert np.allclose(support, ref_support, rtol=0, atol=1e-9)


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("h", [2, 4])
def test_robust_fit_keeps_the_wider_scale_where_a_sharper_one_leaves_no_inlier(monkeypatch, compiled, h):
    """A joint whose depth flickers by +-3 cm every frame has no sample within the 2 cm and
    1 cm scales of the fit: those passes have nothing to fit there. The fit stays at the
    wider scale's estimate instead of the ridge's 0 (the camera's origin, 2.8 m away), which
    the window cleaner took as the joint's position and the bone projection dragged the
    whole arm towards (a serve freeze take: one frame of the arm 0.3 m off)."""
    if not compiled:
        _use_numpy_references(monkeypatch)
    T = 60
    x = np.zeros((T, 2, 3))
    x[:, 0] = [0.3, 1.2, 2.8]
    x[:, 1] = [0.3, 1.0, 2.8]
    x[:, 0, 2] += 0.03 * (-1.0) ** np.arange(T)
    fit, resid, support = (kernels if compiled else robust_fit).robust_temporal_fit(x, np.ones((T, 2)), h)
    assert (support[:, 0, 2] == 0).any()  # the case this is about occurs
    assert np.abs(fit[:, 0, 2] - 2.8).max() < 0.05
    assert np.abs(fit[:, 1] - x[:, 1]).max() < 1e-9  # a steady joint is its samples


def test_clean_window_same_with_kernels_and_references(kinect, monkeypatch):
    """The window cleaner's output does not depend on which implementation runs."""
    x, conf, bones = kinect
    x, conf = x[:60].copy(), conf[:60].copy()
    rng = np.random.default_rng(5)
    spikes = rng.random(x.shape) < 0.1
    x[spikes] += rng.uniform(-0.25, 0.25, size=int(spikes.sum()))
    x[25:40, 7] = np.nan                      # a gap the solver fills
    conf[25:40, 7] = 0.0
    fast = pipeline.clean_window(x, conf, bones, None, 30.0)
    _use_numpy_references(monkeypatch)
    slow = pipeline.clean_window(x, conf, bones, None, 30.0)
    assert np.isfinite(fast.positions).all()
    assert np.abs(fast.positions - slow.positions).max() < 1e-6
    assert np.array_equal(fast.recovered, slow.recovered)
    assert fast.info["estimator"] == slow.info["estimator"]


def test_bone_spread_kernel_is_bit_identical(kinect, monkeypatch):
    x, conf, bones = kinect
    x = x[:61]
    observed = conf[:61] >= 1.0               # tracked only: bones with gaps
    observed[:, 4] = False                    # a joint never seen
    observed[1:, 9] = False                   # seen once
    x = x.copy()
    x[5, 2] = np.nan                          # an observed joint without a value
    cases = [(x, observed, 0.02), (x[:60], observed[:60], 0.02), (x, np.ones_like(observed), 0.2)]
    fast = [pipeline._bone_spread(p, o, bones, m) for p, o, m in cases]
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = [pipeline._bone_spread(p, o, bones, m) for p, o, m in cases]
    assert fast == ref
    assert all(v > 0 for v in ref)
    assert pipeline._bone_spread(x, observed, bones, 10.0) == 0.0   # no bone long enough


def test_worst_bone_quantile_compiled_equals_numpy(kinect, monkeypatch):
    x, conf, bones = kinect
    x = x[:61].copy()
    observed = conf[:61] >= 1.0               # tracked only: bones with gaps
    observed[:, 4] = False                    # a joint never seen
    x[5, 2] = np.nan                          # an observed joint without a value
    x[20:26, 7] += 0.15                       # a hand thrown for 6 frames
    cases = [(x, observed, 0.02, q) for q in (0.5, 0.9, 1.0)] + [(x, np.ones_like(observed), 0.2, 0.9)]
    fast = [pipeline._worst_bone_quantile(p, o, bones, m, q) for p, o, m, q in cases]
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = [pipeline._worst_bone_quantile(p, o, bones, m, q) for p, o, m, q in cases]
    assert fast == ref
    assert ref[2] > 0.1 > ref[0] > 0          # the thrown hand's bones are each frame's worst there
    assert pipeline._worst_bone_quantile(x, observed, bones, 10.0, 0.9) == 0.0   # no bone long enough


@pytest.mark.parametrize("median, keeps_buffer", [("_select_median_compiled", False), ("_rank_median_compiled", True)])
def test_compiled_medians_are_the_sorted_median_bit_for_bit(median, keeps_buffer):
    """The bone spread's medians come from an in-place selection and the live gate's (7-21
    values in a new order every frame) from counting ranks, not a sort: the same value for
    odd and even counts, ties and constant runs, reading only the first n values (the
    rank count leaves them in place)."""
    fn = getattr(kernels, median)
    rng = np.random.default_rng(0)
    for trial in range(3000):
        n = int(rng.integers(1, 130 if not keeps_buffer else 40))
        a = rng.normal(size=n)
        if trial % 3 == 0:
            a = np.round(a, 1)  # ties
        if trial % 7 == 0:
            a[:] = 0.25  # all equal
        s = np.sort(a)
        buf = np.concatenate([a, rng.normal(size=4) - 10.0])  # values beyond n are not read
        before = buf.copy()
        assert fn(buf, n) == (s[(n - 1) // 2] + s[n // 2]) / 2.0
        assert np.array_equal(buf, before) or not keeps_buffer


def test_gauss_newton_kernel_matches_lapack_step(kinect, monkeypatch):
    from streamfix.core import isometry

    x, _, bones = kinect
    N = x[:60]
    rng = np.random.default_rng(1)
    A = N + rng.normal(scale=0.01, size=N.shape)
    Z2 = rng.normal(scale=0.01, size=N.shape)
    lengths = estimate_bone_lengths(N, bones)
    lengths[3] = np.nan                       # ignored bone
    fast = isometry.gauss_newton_step(N, A, Z2, 2.0, 1e3, bones, lengths)
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = isometry.gauss_newton_step(N, A, Z2, 2.0, 1e3, bones, lengths)
    assert np.abs(ref - N).max() > 1e-3      # the step does move the joints
    assert np.abs(fast - ref).max() < 1e-12


def test_live_path_bit_identical_with_compiled_theil_sen_line(shared_data, monkeypatch):
    from streamfix.streaming.live import LivePath

    m = read_motion(shared_data / "kinect_v2" / "Ges03_drawlines.csv")
    rng = np.random.default_rng(0)
    x = m.positions.copy()
    spikes = rng.random(x.shape) < 0.1
    x[spikes] += rng.uniform(-0.25, 0.25, size=int(spikes.sum()))
    valid = m.confidence > 0
    x[~valid] = np.nan

    def run():
        live = LivePath(m.n_joints, m.skeleton.bone_array, m.rate_hz)
        return [live.step(x[i], valid[i], m.timestamps[i]) for i in range(m.n_frames)]

    fast = run()
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = run()
    assert sum(r.any() for _, r in ref) > 10  # the gate did replace samples
    for (y, rec), (y_ref, rec_ref) in zip(fast, ref):
        assert np.array_equal(y, y_ref, equal_nan=True)
        assert np.array_equal(rec, rec_ref)


@pytest.mark.parametrize("fraction", [0.1, 0.5, 1.0])
def test_shorth_mode_kernel_is_bit_identical(kinect, monkeypatch, fraction):
    from streamfix.core import isometry

    x, conf, bones = kinect
    lengths = np.linalg.norm(x[:, bones[:, 0]] - x[:, bones[:, 1]], axis=2)
    lengths = np.where(conf[:, bones[:, 1]] >= 1.0, lengths, np.nan)   # gaps where inferred
    lengths[:, 3] = np.nan                                               # a bone never seen
    lengths[1:, 5] = np.nan                                              # seen once
    fast = isometry._shorth_mode(lengths, fraction)
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = isometry._shorth_mode(lengths, fraction)
    assert np.array_equal(fast, ref, equal_nan=True)
    assert np.isfinite(ref).sum() == lengths.shape[1] - 1


@pytest.mark.parametrize("refine_m", [0.02, None])
def test_length_mode_with_support_kernel_is_bit_identical(kinect, monkeypatch, refine_m):
    from streamfix.core import isometry

    x, conf, bones = kinect
    lengths = np.linalg.norm(x[:, bones[:, 0]] - x[:, bones[:, 1]], axis=2)
    lengths = np.where(conf[:, bones[:, 1]] >= 1.0, lengths, np.nan)   # gaps where inferred
    lengths[::7, 2] += 0.3                                               # a corrupted minority
    lengths[:, 3] = np.nan                                               # a bone never seen
    lengths[1:, 5] = np.nan                                              # seen once
    lengths[:, 6] = np.round(lengths[:, 6], 2)                          # ties in the densest window
    fast = isometry.length_mode_with_support(lengths, 0.01, 0.005, refine_m)
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = isometry.length_mode_with_support(lengths, 0.01, 0.005, refine_m)
    assert np.array_equal(fast[0], ref[0], equal_nan=True)
    assert np.array_equal(fast[1], ref[1])
    assert ref[1][5] == 1 and ref[1][3] == 0 and ref[1].max() > 50


def test_warm_up_compiles_every_kernel():
    import numba

    kernels.warm_up()
    dispatchers = [f for f in vars(kernels).values() if isinstance(f, numba.core.registry.CPUDispatcher)]
    # helpers called only from inside other kernels are compiled with them
    helpers = ("_solve3_first_py", "_sorted_median", "_running_median_loop", "_running_median_wide_loop",
               "_tukey_weights_loop", "_sorted_shorth_mode", "_sorted_densest_mode",
               "_sorted_finite", "_select_inplace", "_select_median", "_rank_median", "_release_rigid_loop",
               "_unit_into", "_pose_bias_frame_loop")
    called = [f for f in dispatchers if f.py_func.__name__ not in helpers]
    assert len(called) >= 8
    assert all(f.signatures for f in called)  # compiled (or loaded), so no first-call stall


def test_kabsch_kernel_matches_the_svd_reference_on_kinect_frames(kinect):
    """PCA gap filling rotates every frame's observed joints onto a reference pose: the
    compiled rotations equal the batched SVD's to rounding on real frames (3, 4 and 6
    joints, the local templates' sizes), are proper rotations, and fit as well."""
    from streamfix.core.pca_normalise import kabsch_svd

    positions = kinect[0]
    for joints in ([4, 5, 6], [8, 9, 10, 11], [0, 1, 2, 3, 20, 12]):
        P = positions[:, joints] - positions[:, joints].mean(axis=1, keepdims=True)
        P = P[np.isfinite(P).all(axis=(1, 2))]
        Q = P[len(P) // 2]
        H = np.swapaxes(P, 1, 2) @ Q
        fast, ref = kernels.kabsch_rotations(H), kabsch_svd(H)
        assert np.abs(fast - ref).max() < 1e-9
        assert np.allclose(np.linalg.det(fast), 1.0) and np.allclose(fast @ np.swapaxes(fast, 1, 2), np.eye(3))
        assert np.abs(np.linalg.norm(P @ fast - Q, axis=(1, 2)) - np.linalg.norm(P @ ref - Q, axis=(1, 2))).max() < 1e-12


def test_kabsch_kernel_on_degenerate_inputs():
    """All-zero H (coincident points): the identity; non-finite: NaN; rank 1 (collinear
    points, no unique best rotation): a proper rotation as good as the SVD's."""
    from streamfix.core.pca_normalise import kabsch_svd

    rng = np.random.default_rng(0)
    line = np.outer(np.linspace(-1, 1, 4), rng.normal(size=3))
    Q = rng.normal(size=(4, 3))
    H = np.stack([np.zeros((3, 3)), np.full((3, 3), np.nan), line.T @ Q])
    R = kernels.kabsch_rotations(H)
    assert np.array_equal(R[0], np.eye(3)) and np.isnan(R[1]).all()
    assert np.isclose(np.linalg.det(R[2]), 1.0)
    ref = kabsch_svd(H[2:])[0]
    assert np.isclose(np.linalg.norm(line @ R[2] - Q), np.linalg.norm(line @ ref - Q))


def test_pca_fill_same_with_the_kabsch_kernel_and_the_svd(kinect, monkeypatch):
    """A whole PCA fill (local templates, every frame normalised) with the compiled
    rotations equals the one with numpy's SVD to well under a micrometre."""
    from streamfix.core.pca_fill import pca_fill

    positions, confidence = kinect[0][:300].copy(), kinect[1][:300]
    observed = (confidence > 0) & np.isfinite(positions).all(axis=2)
    observed[100:160, 6:8] = False  # a forearm and hand lost for 2 s
    observed[200:230, 17:19] = False
    training = np.where(observed[..., None], positions, np.nan)  # the take itself, not the lost samples
    fast = pca_fill(positions, observed, training)[0]
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = pca_fill(positions, observed, training)[0]
    assert np.isfinite(fast[100:160, 6:8]).all()
    assert np.nanmax(np.abs(fast - ref)) < 1e-7


def test_pair_distances_kernel_is_bit_identical_on_a_marker_take_with_gaps(shared_data, monkeypatch):
    """Marker pair distances (rigid pairs, PCA partner ranking) on an optical take with 23 % of
    its samples missing: the kernel gives the numpy reference's values bit for bit, in the same
    memory order (the sums over frames that follow depend on it), so the pair spreads and the
    partner ranking are the same with and without the kernels."""
    from streamfix.core import pca_gapfill, rigid_pairs

    x = read_motion(shared_data / "c3d" / "03_rolling.c3d").positions[:900]
    assert np.isnan(x).any()
    ia, ib = np.triu_indices(x.shape[1], 1)
    fast, ref = kernels.pair_distances(x, ia, ib), rigid_pairs.pair_distances_numpy(x, ia, ib)
    assert fast.shape == ref.shape == (len(x), len(ia)) and fast.strides == ref.strides
    assert np.array_equal(fast, ref)
    assert (ref == 0).any() and np.isfinite(ref).all()  # a NaN difference counts as 0
    obs = np.isfinite(x).all(axis=2)
    spread, ranking = rigid_pairs.pair_distance_spread(x, obs), pca_gapfill._partner_ranking(x, obs)
    monkeypatch.setattr(kernels, "COMPILED", False)
    assert np.array_equal(rigid_pairs.pair_distance_spread(x, obs), spread)
    assert np.array_equal(pca_gapfill._partner_ranking(x, obs), ranking)
