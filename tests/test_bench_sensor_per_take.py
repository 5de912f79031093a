"""bench_sensor's per-take table: how many takes x seeds the engine wins against the baseline
its pooled bar names, and the worst one (a pooled mean can hide short takes that lose)."""
from __future__ import annotations

import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def bench_sensor(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    return importlib.import_module("bench_sensor")


def _record(file: str, seed: int, method: str, err_mm: float, kind: str = "noise") -> dict:
    return {"protocol": "sensor", "kind": kind, "method": method, "file": file, "seed": seed, "err_m": err_mm / 1000}


def test_per_take_counts_wins_against_the_bars_baseline_and_names_the_worst(bench_sensor):
    records = [
        _record("/data/long.bvh", 0, "streamfix", 13.0), _record("/data/long.bvh", 0, "butterworth", 14.0),
        _record("/data/long.bvh", 1, "streamfix", 13.5), _record("/data/long.bvh", 1, "butterworth", 14.0),
        _record("/data/short.bvh", 0, "streamfix", 15.0), _record("/data/short.bvh", 0, "butterworth", 12.0),
        _record("/data/short.bvh", 0, "median_savgol", 1.0),  # not the bar's baseline: ignored
        _record("/data/short.bvh", 0, "streamfix", 99.0, kind="jump"),  # another kind: ignored
    ]
    bars = [{"bar": "streamfix < best baseline (butterworth), all joint-frames", "kind": "noise", "value": 0.0135,
             "target": 0.0137, "ok": True, "method": "streamfix", "baseline": "butterworth"},
            {"bar": "collateral damage <= median_savgol's", "kind": "noise", "value": 0.0, "target": 0.0, "ok": True}]
    (row,) = bench_sensor.per_take(records, bars)
    assert (row["kind"], row["method"], row["baseline"]) == ("noise", "streamfix", "butterworth")
    assert (row["wins"], row["cases"]) == (2, 3)
    assert row["worst_ratio"] == pytest.approx(15.0 / 12.0)
    assert row["worst_take"].endswith("short.bvh") and row["worst_seed"] == 0
    md = bench_sensor.markdown({}, {}, bars, {"takes": 2, "seeds": 2, "rate_hz": 30.0}, [row])
    assert "| noise | streamfix | butterworth | 2/3 | 1.250 |" in md


def test_the_takes_the_prior_did_not_train_on_come_from_its_card(bench_sensor, shared_data):
    """The shared BVH takes split by the shipped prior's model card, and the section that shows the
    corrupted joint-frames' means of the unseen ones."""
    from streamfix.prior.runtime import load_default_prior

    files = sorted((shared_data / "cmu_bvh").glob("*.bvh")) + sorted((shared_data / "xia_bvh").glob("*.bvh"))
    held = set(load_default_prior().card["training"]["held_out"])
    unseen = bench_sensor.prior_held_out_takes(files)
    assert unseen and len(unseen) < len(files)  # the card names some of these takes, not all
    assert {f.stem for f in unseen} == {f.stem for f in files} & held
    summary = {"noise": {"streamfix": {"err_m": 0.021, "err_corrupted_m": 0.020}}}
    md = bench_sensor.markdown(summary, {}, [], {"takes": 1, "seeds": 1, "rate_hz": 30.0}, [],
                               {"takes": [str(unseen[0])], "summary": summary})
    assert "did not train on" in md and md.rstrip().endswith("| noise | 20.0 |")
