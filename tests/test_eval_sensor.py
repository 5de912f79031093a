"""`streamfix eval --protocol sensor` end to end on a real mocap take, and its seam measure."""
from __future__ import annotations

import json
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest

from streamfix.core.metrics import seam_jitter
from streamfix.evaluation.sensor import SCORED_KINDS, handover_frames, summarise
from streamfix.streaming.engine import EngineConfig

METHODS = ("input", "median_savgol", "streamfix")


def _eval(project_root, *argv) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamfix.cli", "eval", *argv], cwd=project_root,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def records(shared_data, project_root) -> list[dict]:
    take = shared_data / "xia_bvh" / "depressed_18_000.bvh"  # 105 frames at 120 Hz: 27 at 30 Hz
    proc = _eval(project_root, str(take), "--protocol", "sensor", "--json", "--seed", "4",
                 "--methods", ",".join(METHODS))
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_cli_scores_every_kind_seed_and_method(records):
    assert {(r["kind"], r["seed"], r["method"]) for r in records} == {
        (k, s, m) for k in SCORED_KINDS for s in (4, 5, 6) for m in METHODS}
    assert len(records) == len(SCORED_KINDS) * 3 * len(METHODS)
    for r in records:
        assert r["protocol"] == "sensor" and r["rate_hz"] == 30.0 and r["n_joints"] == 25
        assert r["n_frames"] == 27 and r["n_corrupted"] + r["n_clean"] == 27 * 25
    cases = defaultdict(set)
    for r in records:  # every method cleaned the same corrupted input
        cases[(r["kind"], r["seed"])].add(r["n_corrupted"])
    assert all(len(v) == 1 for v in cases.values())


def test_cli_scores_what_each_kind_did(records):
    by = {(r["kind"], r["seed"], r["method"]): r for r in records}
    for kind in SCORED_KINDS:
        for seed in (4, 5, 6):
            inp = by[(kind, seed, "input")]
            if kind == "noise":  # touches every sample: nothing is uncorrupted
                assert inp["n_clean"] == 0 and inp["err_clean_m"] is None
                assert 0.003 < inp["err_m"] < 0.03
            elif kind == "dropout":  # the input leaves the limb missing: no comparable error
                assert inp["unfilled"] > 0 and inp["err_m"] is None and inp["err_corrupted_m"] is None
                assert inp["err_clean_m"] == 0.0
                assert by[(kind, seed, "streamfix")]["unfilled"] == 0.0
            elif kind == "flagged":  # only the flags changed: the input is exact everywhere
                assert inp["n_corrupted"] > 0 and inp["err_m"] == 0.0 and inp["err_corrupted_m"] == 0.0
            else:
                assert inp["err_clean_m"] == (0.0 if kind != "mix" else inp["err_clean_m"])
                assert inp["err_corrupted_m"] > {"spike": 0.03, "jump": 0.15}.get(kind, 0.0)
    spike = lambda m: np.mean([by[("spike", s, m)]["err_corrupted_m"] for s in (4, 5, 6)])  # noqa: E731
    assert spike("median_savgol") < 0.5 * spike("input")  # a median removes single-frame spikes
    # a hand-over within the 27 frames on serve's schedule (every method but streamfix is
    # scored there); the file schedule's first hand-over is after 571 frames: no seam to score
    for r in records:
        if handover_frames(27, 30.0, r["method"]).any():
            assert r["seam_ratio"] is not None and r["seam_ratio"] > 0, r
        else:
            assert r["method"] == "streamfix" and r["seam_ratio"] is None, r


def test_cli_table_and_bad_input(shared_data, project_root):
    take = shared_data / "xia_bvh" / "depressed_18_000.bvh"
    proc = _eval(project_root, str(take), "--protocol", "sensor", "--methods", "input,savgol")
    assert proc.returncode == 0, proc.stderr
    assert "mean joint error, mm, corrupted joint-frames" in proc.stdout
    assert all(f"\n{k} " in proc.stdout for k in SCORED_KINDS)
    bad = _eval(project_root, str(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), "--protocol", "sensor")
    assert bad.returncode == 1
    assert "Ges01_wavehand.csv" in bad.stderr and "ground truth" in bad.stderr


def test_handover_frames_follow_each_methods_schedule():
    """Two frames per hop, one hop apart (the start-up hop in a body's first window), on
    serve's schedule for every method but ``streamfix`` (the file schedule); paired and
    sensor measure the same frames."""
    from streamfix.evaluation import paired

    serve, files = EngineConfig(rate_hz=30.0), EngineConfig.for_files(30.0)
    for method, cfg in (("input", serve), ("streamfix_serve", serve), ("streamfix", files)):
        T = cfg.window + 10 * cfg.hop  # ten hand-overs after the first whole window
        seam = handover_frames(T, 30.0, method)
        pairs = np.flatnonzero(seam)[1::2]
        assert len(pairs) >= T // cfg.hop - 3, method
        steps = np.diff(pairs)
        late = pairs[1:] > cfg.window + cfg.hop
        assert set(steps[late]) == {cfg.hop} and set(steps[~late]) == {cfg.startup_hop, cfg.hop}, method
        assert np.array_equal(seam, paired.handover_frames(T, 30.0, method))


def test_seam_jitter_sees_a_kink_at_every_hand_over():
    rng = np.random.default_rng(0)
    t = np.arange(300)
    x = np.zeros((300, 2, 3))
    x[..., 0] = np.sin(t / 20.0)[:, None] + 1e-4 * rng.standard_normal((300, 2))
    seam = handover_frames(300, 30.0)
    on, off = seam_jitter(x, seam)
    assert on / off == pytest.approx(1.0, abs=0.15)
    kinked = x.copy()
    ends = np.flatnonzero(seam)[1::2]
    kinked[..., 1] += 2e-2 * np.cumsum(np.isin(t, ends))[:, None]  # a step at each hand-over
    on, off = seam_jitter(kinked, seam)
    assert on / off > 3.0
    with pytest.raises(ValueError, match=r"\(T,\) seam mask"):
        seam_jitter(x, seam[:-1])


def test_summarise_weights_by_joint_frames():
    base = {"protocol": "sensor", "kind": "spike", "method": "m", "n_frames": 10, "n_joints": 10,
            "err_m": 0.0, "unfilled": 0.0, "seam_d2": 1.0, "other_d2": 1.0, "time_s": 0.0}
    recs = [dict(base, n_corrupted=1, n_clean=99, err_corrupted_m=0.1, err_clean_m=0.0),
            dict(base, n_corrupted=3, n_clean=97, err_corrupted_m=0.5, err_clean_m=None)]
    s = summarise(recs)["spike"]["m"]
    assert s["err_corrupted_m"] == pytest.approx((0.1 + 3 * 0.5) / 4)
    assert s["err_clean_m"] == 0.0 and s["records"] == 2 and s["seam_ratio"] == pytest.approx(1.0)
