"""The Kinect v2 sensor model reproduces the statistics measured on the real recordings."""
from __future__ import annotations

import numpy as np
import pytest

from streamfix.io.kinect_csv import read_kinect_csv
from streamfix.sim.body import generate_clean
from streamfix.sim.measure import measure_kinect
from streamfix.sim.sensor import SensorModel, ar1_hf_properties, fit_ar1
from streamfix.skeletons import KINECT_V2 as K


@pytest.fixture(scope="module")
def measured(shared_data):
    recs = {f.name: read_kinect_csv(f) for f in sorted((shared_data / "kinect_v2").glob("*.csv"))}
    return {
        "pooled": measure_kinect(list(recs.values())),
        "standing": measure_kinect([m for n, m in recs.items() if n.startswith("Ges")]),
        "seated": measure_kinect([recs["seated_joints.csv"]]),
    }


@pytest.fixture(scope="module", params=["standing", "seated"])
def simulated(request, measured):
    profile = request.param
    model = SensorModel.from_measurements(measured[profile], measured["pooled"])
    clean = generate_clean(profile, 150.0, model.rate_hz, measured["standing"]["bone_length"],
                           measured[profile]["spine_base"], seed=5)
    obs = model.apply(clean, seed=6)
    return profile, model, clean, obs, measure_kinect([obs])


def test_jitter_level_per_joint(simulated, measured):
    profile, model, clean, obs, sim = simulated
    real = measured[profile]
    ok = (real["hf_samples"] >= 100) & (sim["hf_samples"] >= 100)
    assert ok.sum() >= 12
    ratio = sim["hf_sigma"][ok] / real["hf_sigma"][ok]
    assert 0.85 < np.median(ratio) < 1.2
    assert np.mean((ratio > 0.7) & (ratio < 1.45)) > 0.9, ratio.round(2)
    # the clean motion itself carries (almost) nothing in that band: the jitter is the sensor's
    clean_hf = measure_kinect([clean])["hf_sigma"]
    assert np.nanmedian(clean_hf) < 0.25 * np.nanmedian(real["hf_sigma"])


def test_jitter_colour(simulated, measured):
    profile, model, clean, obs, sim = simulated
    # the model's colour, measured back, equals what the fit promised, and is close to the real one
    assert sim["hf_band_ratio"] == pytest.approx(ar1_hf_properties(model.noise_rho, model.rate_hz)[1], rel=0.12)
    assert sim["hf_band_ratio"] == pytest.approx(measured["pooled"]["hf_band_ratio"], rel=0.15)


def test_inferred_joints(simulated, measured):
    profile, model, clean, obs, sim = simulated
    real = measured[profile]
    np.testing.assert_allclose(sim["inferred_fraction"], real["inferred_fraction"], atol=0.12)
    well = (real["inferred_runs"] >= 3) & (sim["inferred_runs"] >= 3)
    if well.any():
        ratio = sim["inferred_run_mean"][well] / real["inferred_run_mean"][well]
        assert 0.5 < np.median(ratio) < 2.0, ratio
    assert sim["inferred_bone_dev"] == pytest.approx(real["inferred_bone_dev"], rel=0.3)
    # and they really are off: far more than tracked bones are
    assert sim["inferred_bone_dev"] > 3 * sim["tracked_bone_dev"]


def test_drops_timestamps_outliers(simulated, measured):
    profile, model, clean, obs, sim = simulated
    pooled = measured["pooled"]
    assert sim["drop_rate"] == pytest.approx(pooled["drop_rate"], rel=0.5)
    assert sim["dt_jitter_s"] == pytest.approx(pooled["dt_jitter_s"], rel=0.25)
    assert sim["rate_hz"] == pytest.approx(pooled["rate_hz"], rel=1e-3)
    real = measured[profile]
    thumbs = [K.index("ThumbLeft"), K.index("ThumbRight")]
    ref = np.where(real["spike_candidates"][thumbs] >= 200, real["spike_rate"][thumbs], pooled["spike_rate"][thumbs])
    if sim["spike_candidates"][thumbs].min() > 500:
        ratio = sim["spike_rate"][thumbs] / ref
        assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    trunk = [K.index(n) for n in ("SpineBase", "SpineMid", "ShoulderLeft", "HipRight")]
    assert sim["spike_rate"][trunk].max() < 0.005  # as in the real data: outliers are at the extremities
    assert sim["spike_median_m"] == pytest.approx(pooled["spike_median_m"], rel=0.35)


def test_a_silent_sensor_is_the_identity(measured):
    model = SensorModel.from_measurements(measured["standing"], measured["pooled"])
    model.noise_sigma[:] = 0
    model.inferred_fraction[:] = 0
    model.spike_rate[:] = 0
    model.drop_rate = 0.0
    model.dt_jitter_s = 0.0
    clean = generate_clean("standing", 5.0, model.rate_hz, measured["standing"]["bone_length"], [0, 0, 2], seed=1)
    out = model.apply(clean, seed=2)
    np.testing.assert_array_equal(out.positions, clean.positions)
    np.testing.assert_array_equal(out.timestamps, clean.timestamps)


def test_ar1_fit_recovers_its_own_colour():
    for rho in (-0.4, 0.0, 0.3):
        ratio = ar1_hf_properties(rho, 30.0)[1]
        assert fit_ar1(ratio, 30.0) == pytest.approx(rho, abs=0.011)
