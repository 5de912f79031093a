"""The sensor and paired benchmarks score the engine with a candidate prior (``--prior PATH``), in every
worker process, and say which prior they scored; a bad path fails before any work."""
from __future__ import annotations

import importlib
import json
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def bench_module(monkeypatch):
    """Import a benchmark script as its module (worker processes pickle its functions by module name)."""
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    return importlib.import_module


def test_bench_sensor_scores_the_engine_with_the_given_prior(shared_data, tmp_path, bench_module):
    torch = pytest.importorskip("torch", reason="a candidate prior is trained with the `train` extra")
    from streamfix.io.prior_takes import canonical_take
    from streamfix.prior.data import load_take
    from streamfix.prior.runtime import DEFAULT_CARD, set_default_prior
    from streamfix.prior.train import TrainConfig, export_with_card, train

    torch.manual_seed(0)
    takes = [canonical_take(load_take(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), "kinect_v2")]
    cfg = TrainConfig(epochs=1, steps_per_epoch=1, batch=4, channels=8, latent=4)
    model, history = train(takes, takes, cfg, log=lambda s: None)  # a barely trained candidate
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        export_with_card(model, history, takes, [], tmp_path / "candidate", cfg, log=lambda s: None, evaluate=False)
    bench = bench_module("bench_sensor")
    take = str(shared_data / "xia_bvh" / "depressed_13_000.bvh")
    scores = {}
    try:
        for name, prior in (("shipped", DEFAULT_CARD.parent), ("candidate", tmp_path / "candidate")):
            out = tmp_path / name
            bench.main(["--files", take, "--seeds", "1", "--workers", "2", "--prior", str(prior), "--out", str(out)])
            doc = json.loads((out / "sensor.json").read_text())
            assert doc["meta"]["prior"] == str(prior)
            assert f"Engine prior: `{prior}`" in (out / "sensor.md").read_text()
            scores[name] = doc["summary"]["freeze"]["streamfix"]["err_corrupted_m"]
    finally:
        set_default_prior(None)
    assert scores["shipped"] != scores["candidate"]  # the workers used the prior they were given


def test_a_prior_that_does_not_load_fails_before_any_work(tmp_path, capsys, bench_module):
    """...and leaves the process's default prior as it was (the shipped one here)."""
    from streamfix.prior.runtime import DEFAULT_CARD, load_default_prior

    assert bench_module("bench_sensor").main(["--prior", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "--prior" in capsys.readouterr().err and not (tmp_path / "out").exists()
    with pytest.raises(SystemExit) as exc:
        bench_module("bench_paired").main(["--prior", str(tmp_path / "nowhere")])
    assert exc.value.code == 2 and "prior model card not found" in capsys.readouterr().err
    assert load_default_prior().directory == DEFAULT_CARD.parent
