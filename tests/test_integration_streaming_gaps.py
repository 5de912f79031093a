"""The default streaming window solver bridges long gaps and blackouts (issues 4 and 5).

Real data: the seated Kinect v2 recording (legs mostly *inferred* by the sensor, which
is exactly where low rank alone goes wrong) and a standing gesture recording.
"""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.bridging import BridgingWindowSolver, long_gap_frames, long_missing_mask
from streamfix.streaming.engine import EngineConfig, StreamEngine, ThreadedStreamEngine, alm_window_solver
from streamfix.streaming.offline import clean_motion

NS = 1_000_000_000
LEG = [13, 14, 15]  # KneeLeft, AnkleLeft, FootLeft


@pytest.fixture(scope="module")
def seated(shared_data):
    return read_motion(shared_data / "kinect_v2" / "seated_joints.csv")


@pytest.fixture(scope="module")
def leg_gap(seated):
    """The seated take with knee+ankle+foot missing for 3 s from frame 150; ground truth = the sensor's values."""
    a = 150
    b = a + int(round(3.0 * seated.rate_hz))
    m = seated.copy()
    m.positions = seated.positions.copy()
    m.confidence = seated.confidence.copy()
    m.positions[a:b, LEG] = np.nan
    m.confidence[a:b, LEG] = 0.0
    return m, a, b, seated.positions[a:b][:, LEG].copy()


def test_long_gap_threshold_is_a_third_of_the_window():
    obs = np.ones((60, 25), bool)
    obs[10:29, 0] = False  # 19 frames: the solver's job
    obs[10:30, 1] = False  # 20 frames = W/3: bridged
    obs[:, 2] = False  # never seen in the window: bridged
    mask = long_missing_mask(obs, 30.0)
    assert long_gap_frames(60, 30.0) == 20
    assert not mask[:, 0].any() and mask[10:30, 1].all() and mask[:, 2].all()
    assert not mask[:, 3:].any() and not (mask & obs).any()


def test_the_long_gap_rule_counts_at_most_2_s_of_a_longer_window(shared_data, monkeypatch):
    """``streamfix clean --window 12s``: a leg lost for 2 s is a whole 2 s window but a sixth
    of a 12 s one; left to the low-rank fit there it ended 0.39 m off (CMU 131_01, walking),
    bridged 0.05 m."""
    import streamfix.streaming.bridging as bridging
    from streamfix.evaluation.sensor import ground_truth
    from streamfix.motion import Motion

    assert long_gap_frames(360, 30.0) == long_gap_frames(60, 30.0) == 20  # serve's window: a third
    assert long_gap_frames(360, 120.0) == 80 and long_gap_frames(45, 30.0) == 15
    rate = 30.0
    truth = ground_truth(shared_data / "cmu_bvh" / "131_01.bvh", rate).positions
    leg = [KINECT_V2.joint_names.index(n) for n in ("KneeRight", "AnkleRight", "FootRight")]
    a, b = 100, 160
    x = truth.copy()
    x[a:b, leg] = np.nan
    m = Motion(x, np.where(np.isfinite(x).all(axis=2), 1.0, 0.0), np.arange(len(x)) / rate, rate, KINECT_V2)
    cfg = EngineConfig.for_files(rate, window=360, hop=300, lookahead=300)  # the whole 8 s take in one window
    errors = {}
    for label, scale in (("2 s", bridging.GAP_SCALE_MAX_S), ("whole window", np.inf)):
        monkeypatch.setattr(bridging, "GAP_SCALE_MAX_S", scale)
        out, met = clean_motion(m, cfg)
        errors[label] = float(np.linalg.norm(out.positions[a:b, leg] - truth[a:b, leg], axis=2).mean())
        bridged = met["joints_bridged_pca"] + met["joints_bridged_prior"]
        assert (bridged > 0) == (label == "2 s"), (label, met)
    assert errors["2 s"] < 0.25 * errors["whole window"], errors  # measured 49 vs 389 mm


def test_seated_leg_missing_3s_is_filled_flagged_and_stays_on_the_body(leg_gap, seated):
    m, a, b, gt = leg_gap
    cfg = EngineConfig(rate_hz=m.rate_hz)
    out, met = clean_motion(m, cfg)  # the default window solver
    pos = out.positions[a:b][:, LEG]
    assert np.isfinite(pos).all()
    assert out.recovered[a:b][:, LEG].all()
    assert (out.confidence[a:b][:, LEG] == 0.5).all()
    assert met["solver_errors"] == 0  # no window reached clean_window with a never-seen joint
    assert met["joints_bridged_pca"] + met["joints_bridged_prior"] > 0
    err = np.linalg.norm(pos - gt, axis=2)
    # baseline: the low-rank solver alone in the same engine (no bridging)
    alone, _ = clean_motion(m, cfg, alm_window_solver)
    err_alone = np.linalg.norm(alone.positions[a:b][:, LEG] - gt, axis=2)
    print(f"leg gap 3 s: bridged mean {err.mean() * 100:.1f} cm (max {err.max() * 100:.1f}), "
          f"low rank alone mean {err_alone.mean() * 100:.1f} cm (max {err_alone.max() * 100:.1f})")
    assert err.mean() < 0.5 * err_alone.mean()
    assert err.mean() < 0.12 and err.max() < 0.30
    # the leg keeps its shape: knee-ankle length as in the clean output just before the gap
    before = np.linalg.norm(out.positions[a - 30:a, 14] - out.positions[a - 30:a, 13], axis=1)
    gap_len = np.linalg.norm(pos[:, 1] - pos[:, 0], axis=1)
    assert np.abs(gap_len - np.median(before)).max() < 0.02
    # observed joints elsewhere are cleaned, not replaced
    rest = np.ones(m.n_joints, bool)
    rest[LEG] = False
    d = np.linalg.norm(out.positions[a:b][:, rest] - m.positions[a:b][:, rest], axis=2)
    assert np.median(d) < 0.03


def test_prior_alone_also_bridges_the_leg(leg_gap):
    """Kinect v2 has a shipped prior: with no PCA source the leg comes from D(z*)."""
    m, a, b, gt = leg_gap
    out, met = clean_motion(m, EngineConfig(rate_hz=m.rate_hz), BridgingWindowSolver(sources=("prior",)))
    pos = out.positions[a:b][:, LEG]
    assert np.isfinite(pos).all() and out.recovered[a:b][:, LEG].all()
    assert met["joints_bridged_prior"] > 0 and met["joints_bridged_pca"] == 0
    err = np.linalg.norm(pos - gt, axis=2)
    print(f"leg gap 3 s, prior only: mean {err.mean() * 100:.1f} cm (max {err.max() * 100:.1f})")
    assert err.mean() < 0.15


def _frames(motion, drop=(), blank=(), stream="k", body=3):
    for i in range(motion.n_frames):
        if i in drop:
            continue
        pos = motion.positions[i].copy()
        conf = motion.confidence[i].copy()
        if i in blank:
            pos[:] = np.nan
            conf[:] = 0.0
        t = int(round(i / motion.rate_hz * NS))
        yield SkeletonFrame(stream, 1000 + i, t, KINECT_V2.name, [BodyFrame(body, pos, conf)])


@pytest.mark.parametrize("how", ["dropped", "blank"])
def test_half_second_blackout_is_filled_and_flagged(shared_data, how):
    m = read_motion(shared_data / "kinect_v2" / "Ges03_drawlines.csv")
    a = 120
    gone = set(range(a, a + int(round(0.5 * m.rate_hz))))  # 15 frames
    engine = StreamEngine(KINECT_V2, EngineConfig(rate_hz=m.rate_hz))
    kw = {"drop": gone} if how == "dropped" else {"blank": gone}
    out = []
    for f in _frames(m, **kw):
        out += engine.push(f)
    out += engine.flush()
    clean = [f for k, f in out if k == "clean"]
    live = [f for k, f in out if k == "live"]
    assert len(clean) == len(live) == m.n_frames  # the dropped frames are synthesised
    pos = np.stack([f.bodies[0].positions for f in clean])
    rec = np.stack([f.bodies[0].recovered for f in clean])
    rows = sorted(gone)
    assert np.isfinite(pos[rows]).all()
    assert rec[rows].all()
    if how == "dropped":
        assert all(clean[i].filled for i in rows) and not any(clean[i].filled for i in range(a))
    met = engine.metrics()
    assert met["solver_errors"] == 0
    assert met["joints_bridged_pca"] + met["joints_bridged_prior"] > 0
    err = np.linalg.norm(pos[rows] - m.positions[rows], axis=2)
    lin = m.positions[a - 1] + (m.positions[a + 15] - m.positions[a - 1]) * (np.arange(1, 16) / 16.0)[:, None, None]
    err_lin = np.linalg.norm(lin - m.positions[rows], axis=2)
    print(f"0.5 s blackout ({how}): mean {err.mean() * 100:.1f} cm, linear interpolation {err_lin.mean() * 100:.1f} cm")
    assert err.mean() < 0.10


@pytest.mark.parametrize("threaded", [False, True])
def test_every_frame_once_in_order_with_bridging(leg_gap, threaded):
    m, a, b, _ = leg_gap
    cfg = EngineConfig(rate_hz=m.rate_hz, degrade=False)
    engine = (ThreadedStreamEngine if threaded else StreamEngine)(KINECT_V2, cfg)
    out = []
    for f in _frames(m, blank=set(range(300, 315))):
        out += engine.push(f)
        out += engine.poll()
    out += engine.flush(timeout=60.0)
    engine.close()
    for kind in ("live", "clean"):
        seqs = [f.seq for k, f in out if k == kind]
        assert seqs == list(range(1000, 1000 + m.n_frames)), kind
    clean = [f for k, f in out if k == "clean"]
    assert all(len(f.bodies) == 1 and f.bodies[0].body_id == 3 for f in clean)
    rec = np.stack([f.bodies[0].recovered for f in clean])
    assert rec[a:b][:, LEG].all() and rec[300:315].all()
    assert np.isfinite(np.stack([f.bodies[0].positions for f in clean])).all()


# --------------------------------------------------------------------------- fill quality
# Real recordings, one limb blanked; ground truth = the sensor's own values there.
# "fill" = what the bridging sources produce (base solver replaced by linear interpolation
# of the short gaps, so clean_window's own effect on the limb is not counted: on the
# seated take it moves the inferred leg 5 cm from the sensor even without any gap).

def _blank(motion, joints, a, b):
    m = motion.copy()
    m.positions = motion.positions.copy()
    m.confidence = motion.confidence.copy()
    m.positions[a:b, joints] = np.nan
    m.confidence[a:b, joints] = 0.0
    return m


def _passthrough(positions, confidence, bones, bone_lengths, rate_hz, **kwargs):
    from types import SimpleNamespace

    from streamfix.core.interpolate import interpolate_linear

    x = np.asarray(positions, dtype=np.float64)
    o = np.isfinite(x).all(axis=2) & (np.asarray(confidence) > 0)
    y, _ = interpolate_linear(np.where(o[..., None], x, np.nan), o)
    return SimpleNamespace(positions=y, recovered=~o, state=None, iterations=0, converged=True, info={})


def _trivial(motion, joints, a, b):
    """Mean errors (m) of hold-last-value and of linear interpolation over the gap."""
    p = motion.positions
    gt = p[a:b][:, joints]
    w = ((np.arange(a, b) - (a - 1)) / (b - (a - 1)))[:, None, None]
    lin = p[a - 1, joints][None] + w * (p[b, joints] - p[a - 1, joints])[None]
    hold = np.broadcast_to(p[a - 1, joints], gt.shape)
    return np.linalg.norm(hold - gt, axis=2).mean(), np.linalg.norm(lin - gt, axis=2).mean()


ARM_R = [9, 10, 11, 23, 24]  # ElbowRight, WristRight, HandRight, HandTipRight, ThumbRight


@pytest.mark.parametrize("take, joints, a, b", [
    ("seated_joints.csv", LEG, 150, 240),        # inferred leg, 3 s: PCA source
    ("Ges04_comehere.csv", ARM_R, 60, 105),      # static arm, 45 frames: prior source
])
def test_fill_of_a_nearly_static_limb_is_near_hold_or_linear(shared_data, take, joints, a, b):
    """Before: seated leg 8.7 cm, Ges04 arm 21.0 cm (the sources' own guesses wandered 3-30 cm)."""
    m = read_motion(shared_data / "kinect_v2" / take)
    g = _blank(m, joints, a, b)
    gt = m.positions[a:b][:, joints]
    hold, lin = _trivial(m, joints, a, b)
    # the bridging fill alone (no check of the inferred samples around the gap against it)
    fill, met = clean_motion(g, EngineConfig(rate_hz=m.rate_hz), BridgingWindowSolver(_passthrough, verify_inferred=False))
    assert met["joints_bridged_pca"] + met["joints_bridged_prior"] > 0
    e_fill = np.linalg.norm(fill.positions[a:b][:, joints] - gt, axis=2).mean()
    out, _ = clean_motion(g, EngineConfig(rate_hz=m.rate_hz))
    e_out = np.linalg.norm(out.positions[a:b][:, joints] - gt, axis=2).mean()
    free, _ = clean_motion(g, EngineConfig(rate_hz=m.rate_hz),
                           BridgingWindowSolver(_passthrough, excursion_gain=None, verify_inferred=False))
    e_free = np.linalg.norm(free.positions[a:b][:, joints] - gt, axis=2).mean()
    print(f"{take} gap {a}-{b}: fill {e_fill * 100:.1f} cm (unlimited {e_free * 100:.1f}), output {e_out * 100:.1f}, "
          f"hold {hold * 100:.1f}, linear {lin * 100:.1f}")
    best = min(hold, lin)
    assert e_fill < 1.5 * best       # measured 0.9x (seated) and 1.3x (Ges04)
    assert e_fill < 0.5 * e_free     # the limit is what does it
    assert e_out < 0.07              # the engine's output (clean_window moves the seated leg 5 cm by itself)


def test_fill_of_a_moving_arm_still_beats_hold_and_low_rank(shared_data):
    """Ges01: the waving right arm missing for 1 s (30 frames) while it waves."""
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    a, b = 95, 125
    g = _blank(m, ARM_R, a, b)
    gt = m.positions[a:b][:, ARM_R]
    hold, lin = _trivial(m, ARM_R, a, b)
    cfg = EngineConfig(rate_hz=m.rate_hz)
    out, _ = clean_motion(g, cfg)
    alone, _ = clean_motion(g, cfg, alm_window_solver)
    e = np.linalg.norm(out.positions[a:b][:, ARM_R] - gt, axis=2).mean()
    e_alone = np.linalg.norm(alone.positions[a:b][:, ARM_R] - gt, axis=2).mean()
    print(f"Ges01 waving arm 1 s: output {e * 100:.1f} cm, hold {hold * 100:.1f}, linear {lin * 100:.1f}, "
          f"low rank alone {e_alone * 100:.1f}")
    # the one-model canonical prior (5 layouts, 89 min of data) fills this arm about 3 cm
    # worse than the earlier Kinect-v2-only model did (20.8 vs 17.5 cm): still clearly
    # better than holding or interpolating (28.3 / 24.3 cm). Against low rank alone the
    # margin depends on the solver's warm start at the gap's first windows (a dropped frame
    # just before it, now bridged without the solver: 22.3 cm, 20.1 with it): better, by less
    assert e < 0.9 * hold and e < 0.9 * lin and e < 0.95 * e_alone


@pytest.mark.parametrize("take, joints, a, b", [
    ("seated_joints.csv", LEG, 150, 240),
    ("Ges04_comehere.csv", ARM_R, 60, 105),
    ("Ges04_comehere.csv", [9, 10, 11], 100, 145),   # arm moving inside the gap, hand tip seen
    ("Ges01_wavehand.csv", [9, 10, 11], 60, 90),      # waving, hand tip and thumb seen
])
def test_offline_fill_is_never_much_worse_than_linear(shared_data, take, joints, a, b):
    """fill_motion_gaps on a take with one limb blanked: within 1.5x of linear interpolation
    (before: seated leg 11.0 cm vs 1.8, Ges04 still arm 2.6 vs 1.2), and where the observed
    partners carry the motion it keeps PCA's advantage."""
    from streamfix.gapfill import fill_motion_gaps

    m = read_motion(shared_data / "kinect_v2" / take)
    g = _blank(m, joints, a, b)
    gt = m.positions[a:b][:, joints]
    hold, lin = _trivial(m, joints, a, b)
    out = fill_motion_gaps(g)
    assert out.recovered[a:b][:, joints].all()
    assert np.array_equal(out.positions[g.observed], g.positions[g.observed])
    e = np.linalg.norm(out.positions[a:b][:, joints] - gt, axis=2).mean()
    raw = fill_motion_gaps(g, trust_kappa=None)
    e_raw = np.linalg.norm(raw.positions[a:b][:, joints] - gt, axis=2).mean()
    print(f"offline {take} {a}-{b}: {e * 100:.1f} cm (untrusted fill kept {e_raw * 100:.1f}), "
          f"linear {lin * 100:.1f}, hold {hold * 100:.1f}")
    assert e < 1.5 * lin
    if lin > 0.05:  # the limb moved inside the gap: PCA's motion is kept
        assert e < 0.3 * lin


def test_closed_blackouts_are_left_to_time():
    """Whole frames lost with the joints seen on both sides are the ``time`` source's (a
    cubic spline) on a skeleton without a prior; a blackout open at the window's end, or a
    joint also missing where others are seen, is not."""
    from streamfix.streaming.bridging import closed_blackout_mask

    obs = np.ones((60, 4), dtype=bool)
    obs[20:35] = False         # closed blackout
    obs[10:20, 1] = False      # joint 1 was already missing before it
    obs[50:] = False           # open at the end
    closed = closed_blackout_mask(obs)
    assert closed[20:35][:, [0, 2, 3]].all() and not closed[:, 1].any()
    outside = (np.arange(60) < 20) | (np.arange(60) >= 35)
    assert not closed[outside].any()

    # through the bridge, on a smooth 4-marker motion (no prior knows it): the closed
    # blackout comes back on the spline, the rest from the other sources
    t = np.arange(60) / 30.0
    x = np.stack([np.stack([np.sin(t + k), np.cos(0.5 * t + k), 0.1 * k + 0 * t], axis=1) for k in range(4)], axis=1)
    solver = BridgingWindowSolver()
    fill, done, counts = solver.bridge(np.where(obs[..., None], x, np.nan), obs, 30.0, None, None, None)
    assert counts.get("time") == int(closed.sum())
    assert np.abs(fill[closed] - x[closed]).max() < 1e-3  # a smooth motion: the spline is near exact
