"""Gaps the low-rank solver cannot fill: single dropped frames and whole-frame blackouts.

A stream's most common gap is a frame the sensor dropped, which the engine synthesises
with every joint missing; a whole missing frame is a missing column of the solver's
low-rank model, which nothing in the model recovers (the engine's output there was
0.2-0.9 m off, and ``serve`` publishes those frames flagged ``filled``). Short gaps are
now bridged by the local quadratic through their neighbours (no solver: also 40 % of a
Kinect file's cleaning time), longer whole-frame gaps by each joint's cubic spline.
"""
from __future__ import annotations

import numpy as np

from streamfix.core.interpolate import interpolate_linear, interpolate_spline
from streamfix.core.pipeline import PipelineConfig, clean_window
from streamfix.core.window_gaps import fill_short_gaps
from streamfix.evaluation.registry import run_method
from streamfix.io.bvh import read_bvh
from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.streaming.offline import clean_motion


def _dance(shared_data, frames=240):
    m = read_bvh(shared_data / "cmu_bvh" / "131_01.bvh")  # 120 Hz
    return m.positions[::4][:frames], m.skeleton  # 30 Hz


def _drop(gt, gap, starts):
    x = gt.copy()
    missing = np.zeros(gt.shape[:2], dtype=bool)
    for s in starts:
        missing[s:s + gap] = True
    x[missing] = np.nan
    return x, missing


def test_fill_short_gaps_follows_the_curve_better_than_a_straight_line(shared_data):
    gt, _ = _dance(shared_data)
    for gap in (1, 2, 3):
        x, missing = _drop(gt, gap, range(10, 220, 17))
        quad = fill_short_gaps(np.nan_to_num(x), ~missing, 3)
        line, _ = interpolate_linear(x, ~missing)
        err = lambda y: np.linalg.norm(y - gt, axis=2)[missing].mean()  # noqa: E731
        assert err(quad) < err(line), gap
        assert np.array_equal(quad[~missing], gt[~missing])  # observed samples untouched


def test_a_window_with_short_gaps_only_skips_the_solver(shared_data):
    gt, skel = _dance(shared_data, 60)
    x, missing = _drop(gt, 1, (12, 30, 41))
    res = clean_window(x, None, skel.bone_array, None, 30.0)
    assert res.iterations == 0 and res.info.get("short_gaps_only")
    assert np.linalg.norm(res.positions - gt, axis=2)[missing].mean() < 0.02
    # the solver path still exists (and has the spline for blackouts): a joint lost in a seen frame needs it
    x[20, 3] = np.nan
    solved = clean_window(x, None, skel.bone_array, None, 30.0, PipelineConfig(short_gap_s=0.0, time_gap_s=None))
    assert solved.iterations > 0
    assert np.linalg.norm(solved.positions - gt, axis=2)[missing].mean() < 0.05


def test_engine_fills_whole_frame_blackouts_from_time(shared_data):
    gt, skel = _dance(shared_data, 300)
    for gap in (5, 12):
        x, missing = _drop(gt, gap, range(20, 280, 40))
        conf = (~missing).astype(np.float64)
        y = run_method("streamfix", x, conf, skel.bone_array, 30.0, skeleton=skel)
        spline, _ = interpolate_spline(x, ~missing)
        err = np.linalg.norm(y - gt, axis=2)[missing].mean()
        assert err < 2.0 * np.linalg.norm(spline - gt, axis=2)[missing].mean(), (gap, err)  # was 7-30x


def test_frames_the_engine_synthesises_for_drops_sit_between_their_neighbours(shared_data):
    m = read_kinect_csv(shared_data / "kinect_v2" / "Ges04_comehere.csv")  # drops 5 frames
    out, metrics = clean_motion(m, keep_filled=True)
    assert metrics["frames_filled"] > 0
    synthesised = ~np.isin(np.round(out.timestamps, 6), np.round(m.timestamps, 6))
    inner = np.flatnonzero(synthesised)
    inner = inner[(inner > 0) & (inner < out.n_frames - 1)]
    assert len(inner)
    x = out.positions
    off = np.linalg.norm(x[inner] - 0.5 * (x[inner - 1] + x[inner + 1]), axis=2)
    assert off.max() < 0.03  # was up to 0.9 m


def test_a_forearm_lost_for_four_frames_of_a_fast_swing_is_filled_in_time(shared_data):
    """CMU 131_02 (Kinect v2 joints, 30 Hz, 4 mm of noise), one 10 s window: the right forearm
    and hand missing for 4 frames while they swing at 3 m/s. The window's low-rank solve put
    them at their mean pose, half a metre off; each joint's spline through its samples is
    within a few centimetres (PipelineConfig.time_gap_s), and so is what users get."""
    from streamfix.evaluation.registry import run_method
    from streamfix.evaluation.sensor import ground_truth
    from streamfix.skeletons import KINECT_V2

    truth = ground_truth(shared_data / "cmu_bvh" / "131_02.bvh", 30.0).positions
    x = truth + np.random.default_rng(0).normal(0.0, 0.004, truth.shape)
    arm = [KINECT_V2.index(n) for n in ("ElbowRight", "WristRight", "HandRight", "HandTipRight", "ThumbRight")]
    x[49:53, arm] = np.nan
    conf = np.isfinite(x).all(axis=2).astype(float)

    def error(y):
        return float(np.linalg.norm(y[49:53, arm] - truth[49:53, arm], axis=2).mean())

    timed = error(clean_window(x, conf, KINECT_V2.bone_array, None, 30.0).positions)
    solved = error(clean_window(x, conf, KINECT_V2.bone_array, None, 30.0, PipelineConfig(time_gap_s=None)).positions)
    assert timed < 0.06 and solved > 5 * timed  # measured 37 vs 509 mm
    for method in ("streamfix", "streamfix_serve"):
        assert error(run_method(method, x, conf, KINECT_V2.bone_array, 30.0, skeleton=KINECT_V2)) < 0.06


def test_a_dropped_frame_at_the_window_edge_is_filled_in_time_without_a_solve(shared_data, monkeypatch):
    """A frame the sensor dropped at a window's first or last frame is not a short closed gap,
    but it is a blackout: the spline through the window fills it, and a solve's values there
    would be thrown away. The solver is run only for what no spline fills: a gap open at the
    window's end in a joint whose neighbours are seen."""
    import streamfix.core.alm as alm

    gt, skel = _dance(shared_data, 60)
    calls = []
    real_solve = alm.solve
    monkeypatch.setattr(alm, "solve", lambda *a, **k: calls.append(1) or real_solve(*a, **k))
    for edge in (0, 59):
        x = gt.copy()
        x[edge] = np.nan
        res = clean_window(x, None, skel.bone_array, None, 30.0)
        assert not calls and res.iterations == 0 and res.info.get("solve_skipped"), edge
        assert res.info["blackout_frames"] == 1 and res.recovered[edge].all()
        assert np.linalg.norm(res.positions[edge] - gt[edge], axis=1).mean() < 0.05, edge
    x[20:23, 5] = np.nan  # and a joint lost for 3 frames: a closed gap, its spline's
    res = clean_window(x, None, skel.bone_array, None, 30.0)
    assert not calls and res.iterations == 0 and res.info.get("solve_skipped")
    assert np.linalg.norm(res.positions[20:23, 5] - gt[20:23, 5], axis=1).mean() < 0.05
    x[30, 3] = np.nan
    x[58:, 7] = np.nan  # a joint lost at the window's end, the other joints seen: the solver's
    res = clean_window(x, None, skel.bone_array, None, 30.0)
    assert calls and res.iterations > 0 and not res.info.get("solve_skipped")
