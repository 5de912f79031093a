"""`streamfix eval --protocol paired` end to end on a few real repetitions."""
from __future__ import annotations

import json
import math

import pytest

from streamfix.cli import main
from streamfix.evaluation.paired import run_paired

KEYS = ("mean_error_m", "debiased_mean_m", "debiased_p95_m", "jitter", "jitter_reference", "jitter_ratio",
        "bone_cv", "debiased_slow_m")


def test_cli_json_on_a_few_repetitions(capsys):
    code = main(["eval", "--protocol", "paired", "--limit", "2", "--methods", "input,median_savgol,streamfix",
                 "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    recs = json.loads(captured.out)
    assert {(r["dataset"], r["method"], r["region"]) for r in recs} == {
        (d, m, g) for d in ("uiprmd", "keraal") for m in ("input", "median_savgol", "streamfix")
        for g in ("all", "upper", "lower")}
    by = {(r["dataset"], r["method"], r["region"]): r for r in recs}
    for r in recs:
        assert r["protocol"] == "paired" and r["subset"] == "trustworthy"
        assert all(isinstance(r[k], float) and math.isfinite(r[k]) for k in KEYS), r
        # the seam is scored where a take has a window hand-over: serve's schedule (the baselines)
        # hands over every 1/3 s; a repetition is one window of the file schedule (streamfix)
        if r["method"] == "streamfix":
            assert r["seam_frames"] == 0 and r["seam_ratio"] is None, r
        else:
            assert r["seam_frames"] > 0 and isinstance(r["seam_ratio"], float) and math.isfinite(r["seam_ratio"]), r
        assert r["debiased_mean_m"] <= r["debiased_p95_m"] and r["coverage"] == 1.0
    assert by[("uiprmd", "input", "all")]["n_takes"] == 2 and by[("keraal", "input", "all")]["n_takes"] == 1
    # the shipped sensor-bias model saw UI-PRMD's people: each is scored by a model fitted without them
    assert by[("uiprmd", "streamfix", "all")]["sensor_bias"] == "held-out person"
    assert by[("keraal", "streamfix", "all")]["sensor_bias"] == "auto"  # (none ships for Kinect v2)
    assert "sensor_bias" not in by[("uiprmd", "input", "all")]
    for d in ("uiprmd", "keraal"):
        raw = by[(d, "input", "all")]
        # a raw sensor is rougher than the mocap, aligned in time, centimetres off after debiasing
        assert raw["jitter_ratio"] > 1.5 and raw["lag_frames"] == 0
        assert 0.002 < raw["debiased_mean_m"] < 0.15
        # a zero-phase smoother lowers the jitter and does not delay
        ms = by[(d, "median_savgol", "all")]
        assert ms["jitter"] < 0.7 * raw["jitter"] and abs(ms["lag_frames"]) <= 1
        # the sensor's error is mostly slow, and a smoother leaves its slow part where it was
        assert 0.5 * raw["debiased_mean_m"] < raw["debiased_slow_m"] < raw["debiased_mean_m"]
        assert ms["debiased_slow_m"] == pytest.approx(raw["debiased_slow_m"], rel=0.05)
        # the move of the sensor's joints: none for the input, some for a smoother; the engine's output
        # is also scored with its move scaled down to the real-Kinect bar (never above that bar after)
        assert raw["move_m"] == 0.0 and 0.0 < ms["move_m"] < 0.05
        sf = by[(d, "streamfix", "all")]
        assert 0.0 < sf["move_bar_scale"] <= 1.0 and math.isfinite(sf["debiased_at_move_bar_m"])
        if d == "keraal":  # one take: its scaled move is exactly the bar's (or its own, when within it)
            assert sf["move_m"] * sf["move_bar_scale"] == pytest.approx(min(sf["move_m"], 1.5 * ms["move_m"]))
        assert raw["debiased_at_move_bar_m"] is None and ms["debiased_at_move_bar_m"] is None


def test_cli_table_and_directory_argument(shared_data, capsys):
    code = main(["eval", "--protocol", "paired", str(shared_data / "paired" / "keraal"), "--methods", "input"])
    out = capsys.readouterr().out
    assert code == 0
    assert "keraal (1 takes" in out and "region lower" in out and "uiprmd" not in out


def test_no_take_is_scored_by_a_bias_model_that_saw_its_person(shared_data):
    from streamfix.evaluation.paired import held_out_bias_models
    from streamfix.io.paired import find_takes

    refs = [r for r in find_takes(shared_data / "paired", limit=12) if r.dataset == "uiprmd"]
    models = held_out_bias_models(refs, workers=2)
    assert set(models) == {r.key for r in refs}
    for r in refs:
        subject = r.key.split("_")[2]
        assert subject not in models[r.key].training_subjects and len(models[r.key].training_subjects) == 5


def test_unknown_methods_are_skipped_with_a_warning():
    with pytest.warns(UserWarning, match="no_such_method"):
        recs = run_paired(methods=["input", "no_such_method"], limit=1)
    assert {r["method"] for r in recs} == {"input"}


def test_bad_options_fail_clearly(capsys):
    assert main(["eval", "--protocol", "paired", "--rate", "30", "--methods", "input", "--limit", "1"]) == 1
    assert "sensor's own rate" in capsys.readouterr().err
    assert main(["eval", "--protocol", "paired", "--levels", "10", "--methods", "input", "--limit", "1"]) == 2
    assert "no corruption levels" in capsys.readouterr().err
    assert main(["eval", "--protocol", "noise"]) == 2
    assert "needs FILE" in capsys.readouterr().err
    assert main(["eval", "--protocol", "paired", "/no/such/dir", "--methods", "input"]) == 1
    assert "/no/such/dir" in capsys.readouterr().err


def test_per_person_records_pool_back_to_the_dataset_records():
    """``by_person=True`` adds each UI-PRMD subject's own records; together they are the pooled ones."""
    recs = run_paired(methods=["input", "median_savgol"], limit=12, by_person=True)
    pooled = {(r["dataset"], r["method"], r["region"]): r for r in recs if "person" not in r}
    people = [r for r in recs if "person" in r]
    assert {r["dataset"] for r in people} == {"uiprmd"}  # KERAAL's take names no person
    assert len({r["person"] for r in people}) >= 2 and all(r["person"].startswith("s") for r in people)
    for key, whole in pooled.items():
        mine = [r for r in people if (r["dataset"], r["method"], r["region"]) == key]
        if key[0] != "uiprmd":
            assert not mine
            continue
        assert sum(r["n_takes"] for r in mine) == whole["n_takes"]
        assert sum(r["n_frames"] for r in mine) == whole["n_frames"]
        # pooled over joint-frames: between the people's own values, never outside them
        for k in ("mean_error_m", "debiased_mean_m", "debiased_p95_m", "jitter_ratio"):
            values = [r[k] for r in mine]
            assert min(values) <= whole[k] <= max(values), (key, k)
        assert len({round(r["debiased_mean_m"], 6) for r in mine}) > 1  # each pools its own takes
