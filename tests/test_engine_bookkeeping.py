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


def test_histogram_buckets_are_searchsorted_buckets():
    h = Histogram()
    samples = list(Histogram.BOUNDS) + [0.0, 1e-6, 0.00015, 0.003, 7.0, 1e9]
    for s in samples:
        h.observe(s)
    expected = np.bincount(np.searchsorted(Histogram.BOUNDS, samples), minlength=len(Histogram.BOUNDS) + 1)
    assert np.array_equal(h.counts, expected)
    assert h.snapshot()["count"] == len(samples)
