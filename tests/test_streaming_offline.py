"""Offline cleaning's shortcuts give the streaming engine's ``clean`` output unchanged.

Real recordings, the real default window solver: the engine with the live path turned
off (``EngineConfig(live_output=False)``, what ``clean_motion(topic="clean")`` uses)
must emit the same clean frames as the engine that also computes ``live``.
"""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.io import read_motion
from streamfix.skeletons import KINECT_V2
from streamfix.streaming.engine import EngineConfig, StreamEngine, WindowOutput
from streamfix.streaming.offline import clean_motion, motion_frames


@pytest.fixture(scope="module")
def kinect(shared_data):
    return read_motion(shared_data / "kinect_v2" / "Ges02_balancinghands.csv")


def _engine_clean(motion, cfg):
    engine = StreamEngine(motion.skeleton, cfg)
    out = []
    for frame in motion_frames(motion):
        out += engine.push(frame)
    out += engine.flush()
    return out, engine.metrics()


def test_engine_without_live_path_gives_the_same_clean_output(kinect):
    motion = kinect.slice(0, 120)
    with_live, m_live = _engine_clean(motion, EngineConfig(rate_hz=motion.rate_hz))
    without, m_off = _engine_clean(motion, EngineConfig(rate_hz=motion.rate_hz, live_output=False))
    assert any(kind == "live" for kind, _ in with_live)
    assert not any(kind == "live" for kind, _ in without)
    assert m_off["live_out"] == 0 and m_live["live_out"] > 0
    a = [f for kind, f in with_live if kind == "clean"]
    b = [f for kind, f in without if kind == "clean"]
    assert [f.seq for f in a] == [f.seq for f in b]
    assert [f.sensor_time_ns for f in a] == [f.sensor_time_ns for f in b]
    for fa, fb in zip(a, b):
        assert np.array_equal(fa.bodies[0].positions, fb.bodies[0].positions, equal_nan=True)
        assert np.array_equal(fa.bodies[0].recovered, fb.bodies[0].recovered)
        assert np.array_equal(fa.bodies[0].confidence, fb.bodies[0].confidence)


def test_clean_motion_skips_the_live_path_but_live_topic_still_works(kinect):
    motion = kinect.slice(0, 60)
    clean, metrics = clean_motion(motion)
    assert metrics["live_out"] == 0            # the live path did not run
    assert clean.n_frames == motion.n_frames and np.isfinite(clean.positions).all()
    live, metrics = clean_motion(motion, topic="live")
    assert metrics["live_out"] > 0 and live.n_frames == motion.n_frames
    assert not np.array_equal(live.positions, clean.positions)


@pytest.mark.parametrize("name", ["kinect_v2/Ges01_wavehand.csv", "cmu_bvh/131_01.bvh"])
def test_clean_recording_same_with_kernels_and_numpy_references(shared_data, monkeypatch, name):
    """What ``streamfix clean`` outputs does not depend on the compiled kernels (1e-6 m)."""
    from streamfix.cleaning import clean_recording
    from streamfix.core import kernels

    motion = read_motion(shared_data / name)
    motion = motion.slice(0, min(motion.n_frames, 150))
    fast = clean_recording(motion).motion
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref = clean_recording(motion).motion
    assert np.array_equal(np.isnan(fast.positions), np.isnan(ref.positions))
    assert np.nanmax(np.abs(fast.positions - ref.positions)) < 1e-6
    assert np.array_equal(fast.recovered, ref.recovered)
    assert np.array_equal(fast.confidence, ref.confidence)


def test_offline_clean_equals_engine_clean_when_a_window_fails(kinect):
    """A failed window leaves frames to the live path's value: offline then runs it too."""
    from streamfix.streaming.engine import default_window_solver

    motion = kinect.slice(0, 130)
    cfg = EngineConfig(rate_hz=motion.rate_hz)
    newest = []  # each window's newest frame, in order

    def recording(positions, confidence, bones, bone_lengths, rate_hz, **kwargs):
        newest.append(positions[-1].copy())
        return WindowOutput(positions.copy(), ~(confidence > 0), None, 1, True)

    clean_motion(motion, cfg, recording)
    bad = newest[13]  # the 14th window raises: after the start-up windows (every frame in those has 3)

    def failing_solver():
        inner = default_window_solver()

        def solve(positions, confidence, bones, bone_lengths, rate_hz, **kwargs):
            if np.array_equal(positions[-1], bad, equal_nan=True):
                raise RuntimeError("window failed")
            return inner(positions, confidence, bones, bone_lengths, rate_hz, **kwargs)

        return solve

    engine = StreamEngine(motion.skeleton, cfg, failing_solver())
    out = []
    for frame in motion_frames(motion):
        out += engine.push(frame)
    out += engine.flush()
    expect = np.array([f.bodies[0].positions for kind, f in out if kind == "clean" and not f.filled])
    assert engine.metrics()["solver_errors"] == 1
    assert engine.metrics()["joints_live_fallback"] > 0   # some frames did take the live value
    got, metrics = clean_motion(motion, cfg, failing_solver())
    assert metrics["live_out"] > 0                         # it re-ran with the live path
    assert np.array_equal(got.positions, expect, equal_nan=True)


def test_file_schedule_solves_fewer_windows_and_keeps_its_settings_consistent(kinect):
    """EngineConfig.for_files: 20 s windows every 18 s, 19 s lookahead, 0.5 s crossfade at any
    rate, clamped to what the window allows; the offline clean on it solves a fraction of serve's
    windows; an unknown schedule name is refused."""
    from streamfix.streaming.config import schedule_config

    cfg = EngineConfig.for_files(30.0)
    assert (cfg.window, cfg.hop, cfg.lookahead, cfg.handover_s) == (600, 540, 570, 0.5)
    fast = EngineConfig.for_files(120.0)
    assert (fast.window, fast.hop, fast.lookahead) == (2400, 2160, 2280)
    short = EngineConfig.for_files(30.0, window=30)
    assert short.lookahead == 29 and short.hop == 30
    assert EngineConfig.for_files(30.0, lookahead_s=0.5).hop == 16  # hop <= lookahead + 1
    assert schedule_config("serve", 30.0, hop=None) == EngineConfig(rate_hz=30.0)
    assert schedule_config("file", 30.0, window=None) == cfg
    with pytest.raises(ValueError, match="schedule must be one of file, serve"):
        schedule_config("batch", 30.0)
    with pytest.raises(ValueError, match="handover_s"):
        EngineConfig(rate_hz=30.0, handover_s=0.0)
    with pytest.raises(ValueError, match="window must be >= 4"):
        EngineConfig.for_files(30.0, window=0)  # a bad value is refused, not replaced by the default
    with pytest.raises(ValueError, match="hop must be in"):
        EngineConfig.for_files(30.0, hop=0)
    _, on_files = clean_motion(kinect, cfg)
    _, on_serve = clean_motion(kinect, EngineConfig(rate_hz=kinect.rate_hz))
    assert on_files["windows_solved"] * 3 <= on_serve["windows_solved"] + 3


def test_clean_motion_refuses_when_every_window_fails(kinect):
    from streamfix.streaming.offline import WindowSolverError

    def broken(positions, confidence, bones, lengths, rate_hz, **kwargs):
        raise ImportError("No module named 'pywt'")

    motion = kinect.slice(0, 90)
    engine = StreamEngine(motion.skeleton, EngineConfig(rate_hz=motion.rate_hz), broken)
    for frame in motion_frames(motion):
        engine.push(frame)
    engine.flush()
    m = engine.metrics()
    assert m["solver_errors"] > 0 and m["windows_solved"] == 0
    assert m["first_solver_error"] == "ImportError: No module named 'pywt'"
    with pytest.raises(WindowSolverError, match="every window solve failed.*pywt"):
        clean_motion(motion, window_solver=broken)


@pytest.mark.parametrize("schedule", ["file", "serve"])
def test_push_many_gives_what_push_gives_frame_by_frame(kinect, schedule):
    """The offline engine's runs of frames (push_many: ring and body rows as arrays, clean
    frames finalised in runs) emit the frames push() emits one by one, and the engine
    with the live path emits the same clean frames, through dropped frames, a
    discontinuity, NaN joints, a late frame, a second body for a while, and a frame it
    refuses (raised after the frames before it, which are kept)."""
    from dataclasses import replace as dc_replace

    from streamfix.frames import BodyFrame

    cfg = (EngineConfig.for_files(kinect.rate_hz, window=90, hop=40, lookahead=60) if schedule == "file"
           else EngineConfig(rate_hz=kinect.rate_hz))
    period = int(round(1e9 / kinect.rate_hz))
    once = list(motion_frames(kinect))
    span = int(once[-1].sensor_time_ns) - int(once[0].sensor_time_ns) + period
    frames = [dc_replace(f, seq=k * len(once) + int(f.seq), sensor_time_ns=int(f.sensor_time_ns) + k * span)
              for k in range(3) for f in once]  # the take three times: every ring row is reused
    shift = np.zeros(len(frames), dtype=np.int64)
    shift[40:] += 2 * period   # two dropped frames
    shift[90:] += 5_000_000_000  # a 5 s discontinuity
    out = []
    for i, f in enumerate(frames):
        f = dc_replace(f, sensor_time_ns=int(f.sensor_time_ns) + int(shift[i]))
        if 20 <= i < 25:  # NaN joints
            p = np.array(f.bodies[0].positions)
            p[:, 3:6] = np.nan
            f = dc_replace(f, bodies=[BodyFrame(0, p, f.bodies[0].confidence)])
        if 60 <= i < 70:  # a second body for a while
            f = dc_replace(f, bodies=[f.bodies[0], BodyFrame(1, f.bodies[0].positions + 1.0, f.bodies[0].confidence)])
        out.append(f)
        if i == 50:
            out.append(f)  # late: a repeated seq is dropped
    bad = dc_replace(out[120], bodies=[BodyFrame(0, out[120].bodies[0].positions[:5], out[120].bodies[0].confidence[:5])])
    stream = out[:120] + [bad] + out[120:]

    def run(live: bool, many: bool):
        engine = StreamEngine(kinect.skeleton, dc_replace(cfg, live_output=live))
        got = []
        if many:
            with pytest.raises(ValueError, match="joint"):
                engine.push_many(stream, got)  # stops at the bad frame, the outputs before it kept
            engine.push_many(stream[121:], got)
        else:
            for f in stream:
                try:
                    got += engine.push(f)
                except ValueError:
                    pass
        got += engine.flush()
        clean = [f for kind, f in got if kind == "clean"]
        return clean, engine.counters

    reference, counters = run(live=False, many=False)
    assert counters["frames_dropped_late"] == 1 and counters["frames_rejected"] == 1 and counters["gaps_not_filled"] == 1
    for live, many in ((False, True), (True, False)):
        clean, c = run(live, many)
        assert [(f.seq, f.sensor_time_ns, [b.body_id for b in f.bodies]) for f in clean] == \
            [(f.seq, f.sensor_time_ns, [b.body_id for b in f.bodies]) for f in reference]
        for a, b in zip(clean, reference):
            for x, y in zip(a.bodies, b.bodies):
                np.testing.assert_array_equal(x.positions, y.positions)
                np.testing.assert_array_equal(x.confidence, y.confidence)
                np.testing.assert_array_equal(x.recovered, y.recovered)
        assert c["joints_recovered"] == counters["joints_recovered"] and c["clean_out"] == counters["clean_out"]


@pytest.mark.parametrize("schedule", ["file", "serve"])
def test_push_arrays_gives_what_push_gives_frame_by_frame(kinect, schedule):
    """A file's frames as arrays (push_arrays, what clean_motion feeds: no frame objects for
    the runs) emit the clean frames push() emits one by one, through dropped frames, a 5 s
    discontinuity, NaN joints and a frame out of order; arrays of the wrong shape are
    refused whole, naming the joint count, before any frame is taken."""
    cfg = (EngineConfig.for_files(kinect.rate_hz, window=90, hop=40, lookahead=60) if schedule == "file"
           else EngineConfig(rate_hz=kinect.rate_hz))
    period = int(round(1e9 / kinect.rate_hz))
    pos = np.concatenate([kinect.positions] * 3)  # every ring row is reused
    conf = np.concatenate([kinect.confidence] * 3)
    times = np.arange(len(pos), dtype=np.int64) * period
    times[40:] += 2 * period       # two dropped frames
    times[90:] += 5_000_000_000    # a 5 s discontinuity
    times[200] = times[198]        # out of order: dropped as late
    pos[20:25, 3:6] = np.nan       # NaN joints
    seq0 = 1000

    def clean_of(out):
        return [(f.seq, f.sensor_time_ns, f.bodies[0].positions, f.bodies[0].recovered)
                for kind, f in out if kind == "clean"]

    one = StreamEngine(kinect.skeleton, cfg)
    ref = []
    for k in range(len(pos)):
        ref += one.push(SkeletonFrame("offline", seq0 + k, int(times[k]), kinect.skeleton.name,
                                      [BodyFrame(0, pos[k], conf[k])]))
    ref += one.flush()
    arrays = StreamEngine(kinect.skeleton, cfg)
    got = []
    for start in range(0, len(pos), 97):  # in chunks, as clean_motion feeds it
        arrays.push_arrays("offline", 0, pos[start:start + 97], conf[start:start + 97], times[start:start + 97],
                           seq0 + start, got)
    got += arrays.flush()
    a, b = clean_of(got), clean_of(ref)
    assert [x[:2] for x in a] == [x[:2] for x in b] and len(a) == len(pos) - 1 + one.counters["frames_filled"]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x[2], y[2])
        np.testing.assert_array_equal(x[3], y[3])
    assert arrays.counters["frames_dropped_late"] == one.counters["frames_dropped_late"] == 1
    with pytest.raises(ValueError, match=f"expected {kinect.n_joints} joints"):
        arrays.push_arrays("other", 0, pos[:10, :5], conf[:10, :5], times[:10])
    assert "other" not in arrays.streams


def test_the_file_schedule_hands_over_without_a_seam_on_a_long_take(shared_data):
    """A take of several file windows (CMU 131_02 at 30 Hz, played forwards and backwards
    to 83 s, with the sensor protocol's every-sample jitter): at the file schedule's window
    hand-overs the clean output jitters no more than 1.1x the frames within a hop of them
    (the sensor benchmark's "no seam" bar, which its takes, one window each, no longer reach).
    A hand-over without the crossfade's overlap shows as a seam."""
    from streamfix.core.metrics import seam_jitter
    from streamfix.evaluation.sensor import ground_truth
    from streamfix.motion import Motion
    from streamfix.sim.sensor_errors import apply_sensor_errors

    rate = 30.0
    take = ground_truth(shared_data / "cmu_bvh" / "131_02.bvh", rate).positions
    truth = np.concatenate([take, take[::-1][1:], take[1:], take[::-1][1:]] * 2)
    noisy = apply_sensor_errors(truth, np.random.default_rng(0), ["noise"], rate_hz=rate, min_events=1)
    motion = Motion(noisy.positions, noisy.confidence, np.arange(len(truth)) / rate, rate, KINECT_V2)

    def seam_ratio(cfg):
        out, _ = clean_motion(motion, cfg)
        seam = cfg.handover_frames(len(truth))
        on, off = seam_jitter(out.positions, seam, cfg.hop)
        return on / off, int(seam.sum())

    files = EngineConfig.for_files(rate)
    ratio, n_seam = seam_ratio(files)
    assert n_seam >= 8  # four hand-overs (two frames each) in the take
    assert ratio <= 1.1, ratio
    # the same windows handing over in one frame, with no frames shared beyond it: a seam
    abrupt = EngineConfig.for_files(rate, lookahead=files.hop - 1, handover_s=1.0 / rate)
    assert seam_ratio(abrupt)[0] > 1.1
