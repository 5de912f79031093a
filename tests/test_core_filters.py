"""Properties of the fast baselines in streamfix.core.filters and .interpolate."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from streamfix.core import filters
from streamfix.core.interpolate import cubic_spline_at, interpolate_linear, interpolate_spline
from streamfix.core.metrics import jitter


def _noisy_constant(rate_hz=30.0, n=300, j=4, sigma=0.01, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.uniform(-1, 1, size=(1, j, 3))
    return base + rng.normal(0, sigma, size=(n, j, 3)), base


def test_one_euro_reduces_jitter_of_noisy_constant():
    x, base = _noisy_constant()
    y = filters.one_euro(x, 30.0, min_cutoff=1.0, beta=0.5)
    assert jitter(y[30:]) < 0.25 * jitter(x[30:])
    # and it stays centred on the constant
    assert np.abs(y[30:].mean(axis=0) - base[0]).max() < 0.005


def test_one_euro_ramp_lag_bounded_and_beta_reduces_it():
    rate, v = 60.0, 1.0  # m/s
    t = np.arange(240) / rate
    x = np.zeros((t.size, 1, 3))
    x[:, 0, 0] = v * t
    lag0 = x[-1, 0, 0] - filters.one_euro(x, rate, min_cutoff=1.0, beta=0.0)[-1, 0, 0]
    lag1 = x[-1, 0, 0] - filters.one_euro(x, rate, min_cutoff=1.0, beta=2.0)[-1, 0, 0]
    tau = 1 / (2 * np.pi * 1.0)
    # steady-state lag of a first-order low-pass on a ramp is about v * tau
    assert 0 < lag0 <= v * tau * 1.05
    assert 0 < lag1 < 0.5 * lag0


def test_one_euro_is_rate_aware():
    # the same motion sampled at 30 and 120 Hz ends with (about) the same lag
    lags = []
    for rate in (30.0, 120.0):
        t = np.arange(int(4 * rate)) / rate
        x = np.zeros((t.size, 1, 3))
        x[:, 0, 1] = 0.5 * t
        lags.append(x[-1, 0, 1] - filters.one_euro(x, rate, beta=0.0)[-1, 0, 1])
    assert lags[0] == pytest.approx(lags[1], rel=0.3)


def test_one_euro_missing_joint_does_not_poison_state():
    f = filters.OneEuroFilter(30.0)
    a = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 1.0]])
    f.step(a)
    out = f.step(np.array([[np.nan, np.nan, np.nan], [1.0, 1.0, 1.0]]))
    assert np.allclose(out[0], a[0])  # held, not NaN
    out = f.step(a)
    assert np.all(np.isfinite(out))
    assert np.allclose(out, a)


def test_holt_matches_hand_computed_sdk_steps():
    # SDK defaults: smoothing .5, correction .5, prediction .5, jitter .05 m, max dev .04 m
    f = filters.HoltFilter()
    raw = [0.0, 0.02, 0.03, 0.2]
    expected = [
        0.0,  # first frame: f = x, b = 0
        0.0125,  # f = (0.02 + 0)/2 = .01, b = .5*.01 = .005, y = .01 + .5*.005
        0.019375,  # jitter: d=.02 -> x~=.018; f=.5*.018+.5*(.01+.005)=.0165; b=.00575; y=.0165+.002875
        0.16,  # d > .05 -> x~ = x; f=.111125, b=.0501875, y=.13621875; |y-x|>.04 -> clamp to x-.04
    ]
    for r, e in zip(raw, expected):
        out = f.step(np.array([[r, 0.0, 0.0]]))
        assert out[0, 0] == pytest.approx(e, abs=1e-12)
        assert out[0, 1] == 0.0 and out[0, 2] == 0.0


def test_holt_inferred_doubles_radii():
    p = filters.HoltParams()
    a, b = filters.HoltFilter(p), filters.HoltFilter(p)
    for r in (0.0, 0.0, 0.0, 0.07):
        x = np.array([[r, 0.0, 0.0]])
        ya = a.step(x)
        yb = b.step(x, inferred=np.array([True]))
    # 0.07 is outside 0.05 but inside 0.10: the inferred joint's jitter filter damps it more
    assert yb[0, 0] < ya[0, 0]


def test_holt_missing_joint_resets_and_holds():
    f = filters.HoltFilter()
    for _ in range(5):
        f.step(np.ones((2, 3)))
    out = f.step(np.array([[np.nan] * 3, [1.0, 1.0, 1.0]]))
    assert np.allclose(out[0], 1.0)
    out = f.step(np.array([[2.0, 2.0, 2.0], [1.0, 1.0, 1.0]]))
    assert np.allclose(out[0], 2.0)  # restarted: first frame returns the raw value


@pytest.mark.parametrize("order", [2, 3])
def test_savgol_preserves_polynomials(order):
    rate = 30.0
    t = np.arange(90) / rate
    coef = np.array([0.3, -0.5, 0.8, 0.2])[: order + 1]
    traj = np.polyval(coef, t)
    x = np.stack([traj, 2 * traj, -traj], axis=-1)[:, None, :].repeat(3, axis=1)
    y = filters.savgol(x, rate, polyorder=order)
    assert np.allclose(y, x, atol=1e-9)


def test_savgol_handles_missing_samples():
    rate = 30.0
    t = np.arange(60) / rate
    x = np.zeros((60, 1, 3))
    x[:, 0, 0] = 0.5 * t + 0.1
    obs = np.ones((60, 1), bool)
    obs[20:26] = False
    xin = x.copy()
    xin[~obs] = np.nan
    y = filters.savgol(xin, rate, observed=obs)
    assert np.all(np.isfinite(y))
    assert np.allclose(y, x, atol=1e-9)


def test_median_savgol_removes_isolated_spikes():
    rate = 30.0
    t = np.arange(120) / rate
    x = np.zeros((120, 2, 3))
    x[:, :, 0] = 0.2 * np.sin(2 * np.pi * 0.5 * t)[:, None]
    spiky = x.copy()
    spiky[::10, 0, 0] += 0.25
    inner = slice(10, -10)  # a spike on the very first frame is indistinguishable from motion
    err_ms = np.abs(filters.median_savgol(spiky, rate) - x)[inner].max()
    err_sg = np.abs(filters.savgol(spiky, rate) - x)[inner].max()
    assert err_ms < 0.02
    assert err_ms < 0.3 * err_sg


def test_running_median_ignores_missing():
    x = np.arange(10, dtype=float)[:, None, None] * np.ones((1, 1, 3))
    obs = np.ones((10, 1), bool)
    obs[4] = False
    x[4] = 1000.0  # must not be seen
    m = filters.running_median(x, 3, obs)
    assert m[4, 0, 0] == pytest.approx(4.0)
    assert np.all(m < 100)


def test_linear_interpolation_fills_gaps_and_holds_edges():
    x = np.zeros((10, 2, 3))
    x[:, 0, 0] = np.arange(10)
    obs = np.ones((10, 2), bool)
    obs[[0, 1, 4, 5, 9], 0] = False
    obs[:, 1] = False  # never observed
    xin = x.copy()
    xin[~obs] = np.nan
    y, filled = interpolate_linear(xin, obs)
    assert np.allclose(y[2:9, 0, 0], np.arange(2, 9))
    assert y[0, 0, 0] == 2 and y[1, 0, 0] == 2 and y[9, 0, 0] == 8
    assert np.all(np.isnan(y[:, 1]))
    assert filled[:, 0].tolist() == (~obs[:, 0]).tolist()
    assert not filled[:, 1].any()


def test_spline_interpolation_exact_for_cubic():
    t = np.arange(40, dtype=float)
    x = np.zeros((40, 1, 3))
    x[:, 0, 0] = 1e-4 * (t - 20) ** 3 - 0.01 * t
    obs = np.ones((40, 1), bool)
    obs[12:25] = False
    xin = x.copy()
    xin[~obs] = np.nan
    ys, _ = interpolate_spline(xin, obs)
    yl, _ = interpolate_linear(xin, obs)
    assert np.allclose(ys, x, atol=1e-9)
    assert np.abs(yl - x).max() > 1e-3


def test_spline_groups_equal_one_spline_per_joint():
    # joints observed on the same frames share one spline (a blackout: all of them); the
    # result must be each joint's own spline through its observed frames, whatever the mix
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(5)
    for case in range(12):
        T, J = int(rng.integers(8, 150)), int(rng.integers(1, 26))
        x = np.cumsum(rng.normal(size=(T, J, 3)), axis=0)
        obs = rng.random((T, J)) > rng.uniform(0.05, 0.5)
        if case % 3 == 0:
            obs[:] = True
            obs[T // 3:T // 3 + 4] = False  # a whole-frame blackout
        if case % 3 == 1:
            obs[:, : J // 2 + 1] = obs[:, :1]  # half the joints share a pattern
        obs[:2, 0] = False  # a leading gap holds the nearest sample
        got, filled = interpolate_spline(x, obs)
        ref, _ = interpolate_linear(x, obs)
        t = np.arange(T, dtype=np.float64)
        for j in np.flatnonzero(filled.any(axis=0) & (obs.sum(axis=0) >= 4)):
            ts = t[obs[:, j]]
            inside = filled[:, j] & (t > ts[0]) & (t < ts[-1])
            ref[inside, j] = CubicSpline(ts, x[obs[:, j], j], axis=0)(t[inside])
        assert np.array_equal(np.isnan(got), np.isnan(ref)), case
        assert np.allclose(got, ref, atol=1e-9, equal_nan=True), case


def test_cubic_spline_at_is_scipys_not_a_knot_spline_bit_for_bit():
    # the gap splines evaluate only the intervals holding a query; they must be scipy's
    # CubicSpline exactly (same slope solve, same per-interval sums), knots spaced unevenly
    from scipy.interpolate import CubicSpline

    rng = np.random.default_rng(11)
    for case in range(40):
        n = int(rng.integers(4, 300))
        knots = np.sort(rng.choice(np.arange(3 * n), n, replace=False)).astype(np.float64)
        values = rng.normal(size=(n, int(rng.integers(1, 5)), 3))
        queries = rng.uniform(knots[0], knots[-1], size=int(rng.integers(1, 40)))
        queries[0] = knots[int(rng.integers(0, n))]  # on a knot too
        ref = CubicSpline(knots, values, axis=0, bc_type="not-a-knot")(queries)
        got = cubic_spline_at(knots, values, queries)
        assert got.shape == ref.shape, case
        assert np.array_equal(got, ref), (case, np.abs(got - ref).max())
    with pytest.raises(ValueError, match="at least 4 knots"):
        cubic_spline_at(np.arange(3.0), np.zeros((3, 2)), np.array([0.5]))


def test_spline_at_some_frames_is_the_whole_spline_there():
    # a window that needs its blackout frames alone asks for them; every frame asked for
    # (observed, inside a gap, at an edge, of a joint never seen or seen under 4 times) must
    # get the value, and the filled flag, the whole call gives it
    rng = np.random.default_rng(8)
    for case in range(60):
        T, J = int(rng.integers(2, 90)), int(rng.integers(1, 7))
        x = np.cumsum(rng.normal(size=(T, J, 3)), axis=0)
        obs = rng.random((T, J)) > rng.uniform(0.05, 0.9)
        if case % 3 == 0:
            obs[T // 3:T // 3 + 3] = False  # a blackout
        frames = np.sort(rng.choice(T, size=int(rng.integers(0, T + 1)), replace=False))
        whole, filled = interpolate_spline(x, obs)
        some, some_filled = interpolate_spline(x, obs, frames=frames)
        assert some.shape == (len(frames), J, 3) and some_filled.shape == (len(frames), J)
        assert np.array_equal(some, whole[frames], equal_nan=True), case
        assert np.array_equal(some_filled, filled[frames]), case
        mask = np.zeros(T, dtype=bool)
        mask[frames] = True  # the same frames as a mask
        assert np.array_equal(interpolate_spline(x, obs, frames=mask)[0], whole[frames], equal_nan=True), case


def test_running_median_matches_nanmedian_of_each_shrunken_window():
    # the sort-based median must give np.nanmedian's value for every missing pattern:
    # odd and even observed counts, all-missing windows (NaN), shrunken edge windows
    rng = np.random.default_rng(3)
    for window in (3, 5, 9, 19):
        x = rng.normal(size=(40, 6, 3))
        x[rng.random(x.shape) < 0.4] = np.nan
        x[:, 1] = np.nan  # never observed
        x[10:25, 2] = np.nan  # a gap longer than the window
        m = filters.running_median(x, window, detrend_edges=False)
        half = window // 2
        with warnings.catch_warnings():  # all-NaN windows warn in nanmedian
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.stack([np.nanmedian(x[max(0, t - half):t + half + 1], axis=0) for t in range(40)])
        assert np.array_equal(m, ref, equal_nan=True)


@pytest.mark.parametrize("window", [5, 9, 19])
def test_running_median_edges_follow_a_moving_joint(window):
    """On a ramp the one-sided edge window lags by half its reach; the detrended edges do not,
    and stay robust: an outlier among the edge samples, and missing ones, change nothing."""
    t = np.arange(30, dtype=float)
    x = (0.13 * t)[:, None, None] * np.array([1.0, -0.5, 0.2])  # 13 cm per frame: a fast foot
    x = np.repeat(x, 2, axis=1)
    half = window // 2
    plain = filters.running_median(x, window, detrend_edges=False)
    assert np.abs(plain[0] - x[0]).max() > 0.05 * half
    np.testing.assert_allclose(filters.running_median(x, window), x, atol=1e-12)
    bad = x.copy()
    bad[1, 0] += 2.0  # a 2 m spike next to the first frame
    bad[-2, 1] = np.nan  # a missing sample next to the last
    np.testing.assert_allclose(filters.running_median(bad, window)[[0, -1]], x[[0, -1]], atol=1e-12)


def test_median_savgol_does_not_lag_a_fast_joint_at_a_window_edge(shared_data):
    """Real motion (a Xia take's first frames, foot moving ~4 m/s) in a short window, as the
    engine's first window of a stream sees it: the edge frames stay near the truth."""
    from streamfix.evaluation.sensor import ground_truth

    truth = ground_truth(shared_data / "xia_bvh" / "angry_13_000.bvh", 30.0).positions[:16]
    ms = filters.median_savgol(truth, 30.0)
    edge = np.linalg.norm(ms[[0, -1]] - truth[[0, -1]], axis=-1).mean()
    # the one-sided medians left these frames 7-9 cm off; the median's bias on this curved
    # motion is 0.3-2 cm on the interior frames
    assert edge < 0.03, edge


def test_savgol_keeps_never_observed_joint_missing_and_smooths_the_rest():
    from streamfix.core.filters import savgol

    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(0, 0.01, size=(40, 4, 3)), axis=0)
    x[:, 2] = np.nan
    y = savgol(x, 30.0)
    assert np.isnan(y[:, 2]).all()
    assert np.isfinite(y[:, [0, 1, 3]]).all()


@pytest.mark.parametrize("window_s", [0.1, 0.3, 1.0])
def test_savgol_equals_scipy_interp_mode_on_real_mocap(shared_data, window_s):
    # filters.savgol applies scipy's mode="interp" edge fits as cached linear maps
    from scipy.signal import savgol_filter

    from streamfix.io import read_motion

    m = read_motion(shared_data / "cmu_bvh" / "131_01.bvh")
    x = m.positions[:300]
    got = filters.savgol(x, m.rate_hz, window_s=window_s)
    w = filters.odd_window(window_s, m.rate_hz, minimum=5)
    ref = savgol_filter(x, w, 3, axis=0, mode="interp")
    assert np.abs(got - ref).max() < 1e-10
    assert np.abs(got - x).max() > 1e-4  # it does smooth


def test_savgol_coefficients_are_scipys():
    from scipy.signal import savgol_coeffs

    for window in range(3, 64, 2):
        for order in range(0, min(window, 6)):
            np.testing.assert_allclose(filters.savgol_coefficients(window, order), savgol_coeffs(window, order),
                                       rtol=0, atol=1e-14)


def test_the_cleaning_path_does_not_import_scipy_signal():
    """scipy.signal takes ~0.4 s to import, a third of `streamfix clean`'s start: only the
    baselines that need it (Butterworth, the pose bias's one-pole smoother) import it, when run."""
    import subprocess
    import sys

    code = ("import sys, streamfix.cli, streamfix.cleaning, streamfix.streaming.engine; "
            "print('scipy.signal' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "False", out.stdout + out.stderr
