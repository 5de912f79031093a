"""replay_data/: readable, small, reproducible from sessions.json, never copied from ../shared/data."""
from __future__ import annotations

import json

import numpy as np
import pytest

from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.sim.body import generate_clean
from streamfix.sim.sensor import SensorModel


@pytest.fixture(scope="module")
def manifest(project_root):
    return json.loads((project_root / "replay_data" / "sessions.json").read_text())


def test_sessions_are_small_and_readable(project_root, manifest):
    files = sorted((project_root / "replay_data").glob("*"))
    assert sum(f.stat().st_size for f in files) < 2 * 1024 * 1024
    assert len(manifest) >= 2
    for s in manifest:
        m = read_kinect_csv(project_root / "replay_data" / s["file"])
        assert m.n_frames == s["frames"]
        assert 20.0 <= s["duration_s"] <= 60.0
        assert m.duration_s == pytest.approx(s["duration_s"], abs=0.2)
        assert 29.5 < m.rate_hz < 31.0
        assert (m.confidence == 0.5).mean() == pytest.approx(s["inferred_fraction"], abs=1e-9)
    seated = [s for s in manifest if s["profile"] == "seated"]
    assert seated and seated[0]["inferred_fraction"] > 0.2  # occluded legs, like the real seated recording


def test_regenerated_from_the_manifest(project_root, manifest):
    """README's recipe is the truth: clean motion + sensor model with the listed seeds gives the file."""
    for s in manifest:
        params = dict(s["sensor_model"])
        model = SensorModel(**params)
        clean = generate_clean(s["activity"], s["duration_s"], model.rate_hz, np.array(s["bone_length"]),
                               np.array(s["placement"]), seed=s["seed"], subject_scale=s["subject_scale"])
        obs = model.apply(clean, seed=s["sensor_seed"])
        m = read_kinect_csv(project_root / "replay_data" / s["file"])
        assert obs.n_frames == m.n_frames
        np.testing.assert_allclose(m.positions, obs.positions, atol=0.6e-4)
        np.testing.assert_array_equal(m.confidence, obs.confidence)
        np.testing.assert_allclose(m.timestamps, obs.timestamps + s["clock_offset_s"], atol=2e-7)


def test_no_line_from_the_real_recordings(project_root, shared_data):
    real = set()
    for f in (shared_data / "kinect_v2").glob("*.csv"):
        real.update(line.strip() for line in f.read_text().splitlines())
        real.update(line.split(",", 1)[1] for line in f.read_text().splitlines() if "," in line)
    for f in (project_root / "replay_data").glob("*.csv"):
        for line in f.read_text().splitlines():
            assert line.strip() not in real and line.split(",", 1)[1] not in real
