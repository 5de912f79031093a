"""Blackouts splined in co-rotating frames (streamfix.core.corotating) and the blackout
fill's fallbacks: exact where the room spline is exact, better where segments turn, on
synthetic rigid bodies and on real marker takes (CMU, UI-PRMD's Vicon). Also the rigid
pairs they stand on (streamfix.core.rigid_pairs): spreads measured in frame chunks, and the
pair projection against a per-frame reference."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import pca_blackouts as pb
from streamfix.core.corotating import corotating_spline
from streamfix.core.interpolate import interpolate_linear, interpolate_spline
from streamfix.core.pca_training import TrainingSet
from streamfix.core.rigid_pairs import estimate_rigid_pairs, pair_distance_spread, rigid_neighbours
from streamfix.gapfill import fill_motion_gaps
from streamfix.io import read_motion
from streamfix.motion import Motion
from streamfix.skeletons import Skeleton

RATE = 120.0


def _rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rodrigues: ``(T, 3, 3)`` rotations by ``angles`` (rad) about the unit ``axis``."""
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _two_segments(T: int = 240, seed: int = 0, per_segment: int = 6) -> np.ndarray:
    """``(T, 2 * per_segment, 3)`` m: two rigid marker clusters (radius ~0.1 m), one turning
    at 4 rad/s about a tilted axis, one at -2.5 rad/s about another, both travelling on curves."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / RATE
    out = []
    for axis, rate, offset in (([0.2, 1.0, 0.3], 4.0, 0.0), ([1.0, 0.1, -0.4], -2.5, 0.6)):
        shape = rng.normal(scale=0.06, size=(per_segment, 3))
        shape -= shape.mean(axis=0)
        R = _rotations(np.asarray(axis, dtype=float), rate * t)
        path = np.stack([0.4 * np.sin(1.3 * t) + offset, 1.0 + 0.2 * np.cos(0.9 * t), 0.3 * t], axis=1)
        out.append(np.einsum("tab,jb->tja", R, shape) + path[:, None, :])
    return np.concatenate(out, axis=1)


def _blackout(T: int, a: int, length: int) -> np.ndarray:
    miss = np.zeros(T, dtype=bool)
    miss[a:a + length] = True
    return miss


def _room_spline(x: np.ndarray, miss: np.ndarray) -> np.ndarray:
    obs = np.repeat(~miss[:, None], x.shape[1], axis=1)
    return interpolate_spline(np.where(obs[..., None], x, np.nan), obs)[0][miss]


def test_a_cluster_that_only_travels_gives_the_room_spline():
    """No turn: the centroid spline plus the (constant) offsets is the room spline, exactly."""
    t = np.arange(200) / RATE
    shape = np.random.default_rng(1).normal(scale=0.05, size=(5, 3))
    path = np.stack([np.sin(2 * t), np.cos(3 * t), t ** 2], axis=1)
    x = path[:, None, :] + shape[None]
    miss = _blackout(200, 80, 40)
    np.testing.assert_allclose(corotating_spline(x, miss, n_neighbours=3), _room_spline(x, miss), atol=1e-9)


def test_turning_segments_keep_their_shape_where_the_room_spline_cuts_corners():
    x = _two_segments()
    miss = _blackout(len(x), 90, 72)                          # 0.6 s: 2.4 and 1.5 rad of turn
    truth = x[miss]
    co = corotating_spline(x, miss, n_neighbours=5)
    room = _room_spline(x, miss)
    err = lambda y: float(np.linalg.norm(y - truth, axis=2).mean())  # noqa: E731
    assert err(co) < 0.2 * err(room), (err(co), err(room))
    # rigid distances: the clusters' pair distances stay as they were, the room spline's do not
    pairs = estimate_rigid_pairs(x, k=20)
    dist = lambda y: np.linalg.norm(y[:, pairs[:, 0]] - y[:, pairs[:, 1]], axis=2)  # noqa: E731
    assert np.abs(dist(co) - dist(truth)).max() < 1e-9
    assert np.abs(dist(room) - dist(truth)).max() > 5e-3


def test_a_stack_of_windows_is_each_window_on_its_own():
    x = np.stack([_two_segments(seed=s) for s in range(3)])
    miss = _blackout(x.shape[1], 60, 30)
    nb = rigid_neighbours(pair_distance_spread(x[0]), 4)
    stacked = corotating_spline(x, miss, nb)
    assert stacked.shape == (3, 30, 12, 3)
    for k in range(3):
        np.testing.assert_allclose(stacked[k], corotating_spline(x[k], miss, nb), atol=1e-12)


def test_fewer_than_two_partners_is_the_room_spline():
    x = _two_segments()
    miss = _blackout(len(x), 100, 30)
    np.testing.assert_allclose(corotating_spline(x, miss, n_neighbours=1), _room_spline(x, miss), atol=1e-9)


def test_rigid_neighbours_are_the_markers_of_the_same_segment():
    x = _two_segments()
    nb = rigid_neighbours(pair_distance_spread(x), 5)
    assert (nb[:6] < 6).all() and (nb[6:] >= 6).all()
    # the pair picker reads the same spread
    pairs = estimate_rigid_pairs(x, k=30)
    assert ((pairs < 6).all(axis=1) | (pairs >= 6).all(axis=1)).all()


@pytest.fixture(scope="module")
def take_85(shared_data):
    return read_motion(shared_data / "c3d" / "85_02.c3d")


def test_real_marker_blackouts_beat_the_room_spline(take_85):
    """CMU 85_02 (41 markers, 120 Hz): 0.25 s blackouts in six places of the take."""
    x = take_85.positions
    co, room = [], []
    for a in np.linspace(60, len(x) - 100, 6).astype(int):
        miss = _blackout(len(x), a, 30)
        truth = x[miss]
        co.append(np.linalg.norm(corotating_spline(x, miss) - truth, axis=2).mean())
        room.append(np.linalg.norm(_room_spline(x, miss) - truth, axis=2).mean())
    assert np.mean(co) < 0.97 * np.mean(room), (np.mean(co), np.mean(room))


def test_a_take_shorter_than_the_blackout_window_is_splined_not_interpolated_linearly(take_85):
    """No complete training window fits (the take is shorter than the window, the blackout
    in it): the spline fills it, where the linear fallback used to (7x the spline's error on
    UI-PRMD's Vicon repetitions)."""
    x = take_85.positions[300:450]
    obs = np.ones(x.shape[:2], dtype=bool)
    obs[60:90] = False
    xin = np.where(obs[..., None], x, np.nan)
    out, filled = pb.fill_blackouts(xin, obs, TrainingSet([xin]), window=200)
    assert filled[~obs].all()
    np.testing.assert_allclose(out[~obs], interpolate_spline(xin, obs)[0][~obs], atol=1e-9)
    lin = interpolate_linear(xin, obs)[0]
    assert np.linalg.norm(out - x, axis=2)[~obs].mean() < 0.5 * np.linalg.norm(lin - x, axis=2)[~obs].mean()
    co, _ = pb.fill_blackouts(xin, obs, TrainingSet([xin]), window=200, corotating=True)
    np.testing.assert_allclose(co[~obs].reshape(30, -1, 3), corotating_spline(x, ~obs.all(axis=1)), atol=1e-9)


def test_one_training_window_is_no_basis_to_trust():
    """A single training window leaves nothing to cross-validate the blend on: the spline."""
    windows = np.random.default_rng(0).normal(size=(1, 40, 9))
    assert pb._spline_blend_weight(windows, _blackout(40, 15, 10), 2, np.inf, 3) == 0.0


def test_vicon_repetitions_blackouts_filled_at_least_as_well_as_the_spline(shared_data):
    """UI-PRMD's Vicon (39 Plug-in-Gait markers, 100 Hz, people not in CMU), the whole
    ``streamfix clean`` marker fill: 0.2 s blackouts mid-repetition."""
    path = shared_data / "paired" / "uiprmd" / "uiprmd_s01-s06.npz"
    z = np.load(path)
    unit = float(z["vicon_unit_m"])
    keys = sorted(k for k in z.files if k.startswith("vicon_"))[:40]
    sk = Skeleton("vicon39", tuple(f"m{i}" for i in range(39)), ())
    errs = {"fill": [], "spline": [], "linear": []}
    for key in keys:
        raw = z[key]
        if raw.ndim != 3 or len(raw) < 150 or (raw == 0).all(axis=2).any():
            continue
        x = raw.astype(np.float64) * unit
        T = len(x)
        obs = np.ones((T, 39), dtype=bool)
        obs[T // 2 - 10:T // 2 + 10] = False
        xin = np.where(obs[..., None], x, np.nan)
        m = Motion(xin, obs.astype(np.float64), np.arange(T) / 100.0, 100.0, sk)
        for name, y in (("fill", fill_motion_gaps(m).positions), ("spline", interpolate_spline(xin, obs)[0]),
                        ("linear", interpolate_linear(xin, obs)[0])):
            errs[name].append(np.linalg.norm(y - x, axis=2)[~obs].mean())
        if len(errs["fill"]) == 10:
            break
    assert len(errs["fill"]) == 10
    fill, spline, linear = (float(np.mean(errs[k])) for k in ("fill", "spline", "linear"))
    assert fill <= 1.02 * spline and fill < 0.3 * linear, (fill, spline, linear)


def test_serve_bridge_splines_marker_blackouts_in_co_rotating_frames():
    """The streaming bridge's ``time`` source on a marker set: whole-frame blackouts from
    the co-rotating spline, other samples as the room spline left them, a marker never
    seen left alone."""
    from streamfix.core.corotating import corotating_blackouts

    x = _two_segments(per_segment=10)                         # 20 markers
    obs = np.ones(x.shape[:2], dtype=bool)
    obs[90:162] = False                                       # a blackout
    obs[20:30, 3] = False                                     # a marker's own gap
    obs[:, 19] = False                                        # a marker never seen
    temporal = interpolate_spline(np.where(obs[..., None], x, np.nan), obs)[0]
    temporal[:, 19] = np.nan
    out = corotating_blackouts(temporal, obs)
    empty = ~obs.any(axis=1)
    np.testing.assert_array_equal(out[~empty], temporal[~empty])
    assert np.isnan(out[:, 19]).all()
    np.testing.assert_allclose(out[empty][:, :19], corotating_spline(temporal[:, :19], empty), atol=1e-12)
    err = lambda y: np.linalg.norm(y[empty][:, :19] - x[empty][:, :19], axis=2).mean()  # noqa: E731
    assert err(out) < 0.75 * err(temporal), (err(out), err(temporal))


def test_the_partner_count_follows_the_marker_count():
    """A fifth of the markers, 2 to 8: with 8 partners of 11 markers, the clusters straddled
    the two segments and lost to the room spline; 2 follow each segment."""
    from streamfix.core.corotating import neighbour_count

    assert [neighbour_count(j) for j in (3, 11, 20, 41, 90)] == [2, 2, 4, 8, 8]
    x = _two_segments()[:, :11]                               # one segment of 6, one of 5
    miss = _blackout(len(x), 90, 72)
    err = lambda y: np.linalg.norm(y - x[miss], axis=2).mean()  # noqa: E731
    assert err(corotating_spline(x, miss)) < 0.75 * err(_room_spline(x, miss))
    assert err(corotating_spline(x, miss, n_neighbours=8)) > err(_room_spline(x, miss))


def test_pair_spread_is_computed_in_frame_chunks_as_in_one_pass(monkeypatch):
    """A long take's pair distances are measured a chunk of frames at a time (memory): the
    same spread as the whole take at once, missing samples left out."""
    import streamfix.core.rigid_pairs as rp

    x = _two_segments() + np.random.default_rng(3).normal(scale=1e-3, size=(240, 12, 3))
    obs = np.random.default_rng(4).random((240, 12)) > 0.1
    x[~obs] = np.nan
    ia, ib = np.triu_indices(12, 1)
    d = np.linalg.norm(x[:, ia] - x[:, ib], axis=2)
    expected = np.array([np.nanstd(d[:, p]) for p in range(len(ia))])
    monkeypatch.setattr(rp, "SPREAD_CHUNK_FRAMES", 7)
    spread = rp.pair_distance_spread(x, obs)
    np.testing.assert_allclose(spread[ia, ib], expected, rtol=1e-9)
    assert np.isinf(np.diag(spread)).all()


def _project_reference(x, movable, pairs, dmin, dmax, iterations=30):
    """project_pair_distances written out per frame and pair (the test's reference)."""
    x = x.copy()
    lo, hi = dmin + 0.02 * (dmax - dmin), dmax - 0.02 * (dmax - dmin)
    for _ in range(iterations):
        moved = False
        new = x.copy()
        for t in range(len(x)):
            acc = np.zeros_like(x[t])
            cnt = np.zeros(len(x[t]))
            for p, (a, b) in enumerate(pairs):
                v = x[t, b] - x[t, a]
                L = np.linalg.norm(v)
                if not (L > 0 and (L < lo[p] or L > hi[p])):
                    continue
                moved = True
                ends = [e for e in (a, b) if movable[t, e]]
                step = (L - np.clip(L, lo[p], hi[p])) / L * v
                for e in ends:
                    acc[e] += (step if e == a else -step) / len(ends)
                    cnt[e] += 1
            new[t] += acc / np.maximum(cnt, 1)[:, None]
        x = new
        if not moved:
            break
    return x


def test_pair_projection_matches_its_per_frame_reference():
    from streamfix.core.rigid_pairs import pair_distance_ranges, project_pair_distances

    truth = _two_segments(T=40)
    obs = np.ones(truth.shape[:2], dtype=bool)
    obs[10:25, [1, 2, 7]] = False
    obs[30, :] = False
    rng = np.random.default_rng(5)
    guess = truth + np.where(obs[..., None], 0.0, rng.normal(scale=0.02, size=truth.shape))
    pairs = estimate_rigid_pairs(truth, obs, k=25)
    dmin, dmax = pair_distance_ranges(truth, obs, pairs)
    out = project_pair_distances(guess, ~obs, pairs, dmin, dmax)
    np.testing.assert_allclose(out, _project_reference(guess, ~obs, pairs, dmin, dmax), atol=1e-12)
    np.testing.assert_array_equal(out[obs], guess[obs])       # observed samples never move
    assert np.abs(out - truth)[~obs].mean() < np.abs(guess - truth)[~obs].mean()
