"""The live path's fused compiled step (streamfix.core.kernels.live_step) against the numpy path.

Bit for bit on a real Kinect v2 recording with spikes, dropped joints and bone lengths
set, and the two paths may hand over to each other mid-stream (they share their state).
"""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.core import kernels
from streamfix.io import read_motion
from streamfix.streaming.live import LiveConfig, LivePath


@pytest.fixture(scope="module")
def corrupted(shared_data):
    m = read_motion(shared_data / "kinect_v2" / "Ges03_drawlines.csv")
    rng = np.random.default_rng(7)
    x = m.positions.copy()
    spikes = rng.random(x.shape) < 0.1
    x[spikes] += rng.uniform(-0.25, 0.25, size=int(spikes.sum()))
    valid = m.confidence > 0
    valid[40:60, 7] = False                    # a joint gone for 20 frames
    valid[100:103] = False                     # a whole-body dropout
    x[~valid] = np.nan
    bones = m.skeleton.bone_array
    lengths = np.nanmedian(np.linalg.norm(m.positions[:, bones[:, 1]] - m.positions[:, bones[:, 0]], axis=2), axis=0)
    lengths[3] = np.nan                        # a bone without a length is left alone
    return m, x, valid, lengths


def _run(m, x, valid, lengths, cfg, switch_at=None, monkeypatch=None):
    live = LivePath(m.n_joints, m.skeleton.bone_array, m.rate_hz, cfg)
    out = []
    for i in range(m.n_frames):
        if i == 50:
            live.set_bone_lengths(lengths)
        if switch_at is not None and i == switch_at:
            monkeypatch.setattr(kernels, "COMPILED", not kernels.COMPILED)
        y, rec = live.step(x[i], valid[i], m.timestamps[i])
        out.append((y.copy(), rec.copy()))
    return out, live.gated_total


@pytest.mark.parametrize("project", [True, False])
def test_fused_live_step_is_bit_identical_to_numpy_path(corrupted, monkeypatch, project):
    m, x, valid, lengths = corrupted
    cfg = LiveConfig(project=project)
    assert kernels.COMPILED
    fast, gated_fast = _run(m, x, valid, lengths, cfg)
    monkeypatch.setattr(kernels, "COMPILED", False)
    ref, gated_ref = _run(m, x, valid, lengths, cfg)
    assert gated_ref > 10 and gated_fast == gated_ref  # the gate did replace samples
    moved = 0
    for (y, rec), (y_ref, rec_ref) in zip(fast, ref):
        assert np.array_equal(y, y_ref, equal_nan=True)
        assert np.array_equal(rec, rec_ref)
        moved += int(np.isfinite(y_ref).all())
    assert moved > 0.9 * m.n_frames


def test_paths_share_state_when_switched_mid_stream(corrupted, monkeypatch):
    m, x, valid, lengths = corrupted
    ref, _ = _run(m, x, valid, lengths, LiveConfig())
    for switch in (1, 75, 150):
        with monkeypatch.context() as mp:
            got, _ = _run(m, x, valid, lengths, LiveConfig(), switch_at=switch, monkeypatch=mp)
        for (y, rec), (y_ref, rec_ref) in zip(got, ref):
            assert np.array_equal(y, y_ref, equal_nan=True)
            assert np.array_equal(rec, rec_ref)
