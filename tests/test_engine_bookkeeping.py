"""The engine's per-frame bookkeeping shortcuts give what the plain computation gives.

Clean-output bone lengths are measured once per hop in one array call: every row of the
body's memory must equal the lengths of the clean frame it came from, measured alone,
and the clean lengths must be their median. Latency buckets must be numpy's
``searchsorted`` buckets, bounds included.
"""
from __future__ import annotations

import numpy as np

from streamfix.io import read_motion
from streamfix.streaming.engine import EngineConfig, Histogram, StreamEngine
from streamfix.streaming.offline import motion_frames


def test_clean_bone_lengths_measured_per_hop_equal_frame_by_frame(shared_data):
    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    cfg = EngineConfig(rate_hz=m.rate_hz)
    engine = StreamEngine(m.skeleton, cfg)
    clean = []
    for frame in motion_frames(m):
        clean += [f for kind, f in engine.push(frame) if kind == "clean"]
    body = next(iter(engine.streams["offline"].bodies.values()))
    bones = m.skeleton.bone_array
    n = body.clean_bones_n
    assert n == len(clean) > 4 * cfg.hop
    measured = (n // cfg.hop) * cfg.hop  # rows filled so far; the rest wait for the hop
    assert len(body.clean_pending) == n - measured
    for i, f in enumerate(clean[:measured]):
        pos = f.bodies[0].positions
        alone = np.linalg.norm(pos[bones[:, 1]] - pos[bones[:, 0]], axis=1)
        assert np.array_equal(body.clean_bones[i % len(body.clean_bones)], alone)
    rows = body.clean_bones[: min(measured, len(body.clean_bones))]
    assert np.array_equal(body.clean_lengths, np.median(rows, axis=0))
    # the frames kept for the next hop are copies: changing an emitted frame changes nothing
    assert body.clean_pending, "this take must end between two hops"
    clean[-1].bodies[0].positions[:] = 0.0
    assert np.isfinite(body.clean_pending[-1]).all() and np.abs(body.clean_pending[-1]).max() > 0.1
    engine.flush()


def test_clean_bone_lengths_filed_in_runs_equal_frame_by_frame(shared_data):
    # the offline engine files a window's worth of clean frames at once: any split into runs
    # (runs within a hop, across several hops, longer than the memory) leaves the same memory,
    # pending frames and median as filing them one by one
    from types import SimpleNamespace

    from streamfix.streaming.bone_lengths import sample_clean_bones

    m = read_motion(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    bones, hop, cap = m.skeleton.bone_array, 10, 45
    frames = m.positions  # 154 frames: more than the memory holds, ending between two hops

    def fresh():
        return SimpleNamespace(clean_bones_n=0, clean_pending=[], clean_lengths=None,
                               clean_bones=np.full((cap, len(bones)), np.nan))

    one = fresh()
    last_one = [sample_clean_bones(one, frames[i:i + 1], bones, hop) for i in range(len(frames))]
    rng = np.random.default_rng(4)
    for trial in range(5):
        sizes = rng.integers(1, 2 * hop, size=len(frames)) if trial < 4 else np.array([3, 120, 7, 24])
        cuts = np.concatenate([[0], np.cumsum(sizes)])
        cuts = np.unique(np.clip(cuts, 0, len(frames)))
        runs = fresh()
        for a, b in zip(cuts[:-1], cuts[1:]):
            est = sample_clean_bones(runs, frames[a:b], bones, hop)
            newest = next((e for e in reversed(last_one[a:b]) if e is not None), None)
            assert (est is None) == (newest is None), (trial, a, b)
            if est is not None:
                assert np.array_equal(est, newest)
        assert runs.clean_bones_n == one.clean_bones_n == len(frames)
        assert np.array_equal(runs.clean_bones, one.clean_bones, equal_nan=True), trial
        assert np.array_equal(runs.clean_lengths, one.clean_lengths), trial
        assert len(runs.clean_pending) == len(frames) % hop > 0
        assert np.array_equal(np.asarray(runs.clean_pending), np.asarray(one.clean_pending)), trial


def test_histogram_buckets_are_searchsorted_buckets():
    h = Histogram()
    samples = list(Histogram.BOUNDS) + [0.0, 1e-6, 0.00015, 0.003, 7.0, 1e9]
    for s in samples:
        h.observe(s)
    expected = np.bincount(np.searchsorted(Histogram.BOUNDS, samples), minlength=len(Histogram.BOUNDS) + 1)
    assert np.array_equal(h.counts, expected)
    assert h.snapshot()["count"] == len(samples)
