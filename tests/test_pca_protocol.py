"""The long-gaps and blackout protocols (streamfix eval) on real CMU marker data."""
from __future__ import annotations

import numpy as np

from streamfix.evaluation.long_gaps import PROTOCOLS, make_gaps, run_blackout, run_long_gaps
from streamfix.evaluation.registry import discover_protocols

KEYS = {"file", "rate_hz", "protocol", "level", "method", "aje_m", "abe_m", "jitter",
        "gap_frames", "gap_count", "gap_mae_m"}


def test_protocols_are_discovered():
    found = discover_protocols()
    assert found["long-gaps"] is PROTOCOLS["long-gaps"] and found["blackout"] is PROTOCOLS["blackout"]


def test_make_gaps_evenly_spaced_distinct_joints():
    miss, gaps = make_gaps(810, 41, 5, 100, np.random.default_rng(1))
    assert len(gaps) == 5 and len({j for j, _, _ in gaps}) == 5
    assert miss.sum() == 500 and not miss[0].any() and not miss[-1].any()
    starts = [s for _, s, _ in gaps]
    assert len(set(np.diff(starts))) <= 2                   # even spacing (up to rounding)


def test_long_gaps_records_and_pca_beats_interpolation(shared_data):
    path = shared_data / "c3d" / "85_02.c3d"
    recs = run_long_gaps([path], levels=[80], seed=3, methods=["pca", "linear", "spline"])
    assert len(recs) == 3
    for r in recs:
        assert KEYS <= set(r) and r["protocol"] == "long-gaps"
        assert r["gap_frames"] == 80 and r["gap_count"] == 5
    mae = {r["method"]: r["gap_mae_m"] for r in recs}
    assert mae["pca"] <= 0.5 * mae["linear"] and mae["pca"] < mae["spline"]


def test_blackout_records(shared_data):
    path = shared_data / "c3d" / "135_02.c3d"
    recs = run_blackout([path], levels=[10], seed=0, methods=["pca", "linear"])
    assert {r["method"] for r in recs} == {"pca", "linear"}
    for r in recs:
        assert KEYS <= set(r) and r["gap_frames"] == 20 and r["level"] == 10.0
    mae = {r["method"]: r["gap_mae_m"] for r in recs}
    assert mae["pca"] < 0.020 and mae["pca"] < mae["linear"]


def test_engine_fills_marker_blackouts_close_to_the_spline(shared_data):
    """What ``clean`` writes for a marker file (the gap filler, then the streaming engine)
    across whole-frame blackouts of real markers: within 1.1x the cubic spline's error. The
    engine's PCA bridge used to fill them, at 2x the spline's error here."""
    from streamfix.core.interpolate import interpolate_spline
    from streamfix.evaluation.registry import load_motion, run_method

    m = load_motion(shared_data / "c3d" / "85_02.c3d")
    x, rate, sk = m.positions, m.rate_hz, m.skeleton
    L = 30  # 0.25 s, in the middle of the protocol's 200-frame windows
    err_engine, err_spline = [], []
    for s in np.linspace(0, m.n_frames - 200, 4).astype(int):
        a = s + (200 - L) // 2
        obs = np.ones(x.shape[:2], dtype=bool)
        obs[a:a + L] = False
        xin = np.where(obs[..., None], x, np.nan)
        y = run_method("streamfix", xin, obs.astype(float), sk.bone_array, rate, skeleton=sk)
        err_engine.append(np.linalg.norm(y[a:a + L] - x[a:a + L], axis=2).mean())
        sp = interpolate_spline(xin, obs)[0]
        err_spline.append(np.linalg.norm(sp[a:a + L] - x[a:a + L], axis=2).mean())
    assert np.mean(err_engine) <= 1.1 * np.mean(err_spline), (err_engine, err_spline)
