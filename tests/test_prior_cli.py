"""`streamfix train-prior` (exists, names the torch extra, is deterministic) and `clean --prior PATH`."""
from __future__ import annotations

import subprocess
import sys


def test_train_prior_without_torch_names_the_extra(tmp_path):
    code = (
        "import sys\n"
        "sys.modules['torch'] = None  # as if PyTorch were not installed\n"
        "from streamfix.cli import main\n"
        f"sys.exit(main(['train-prior', '--out', {str(tmp_path)!r}]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "pip install streamfix[train]" in proc.stderr
    assert not any(tmp_path.iterdir())


def test_train_prior_help_lists_its_options():
    proc = subprocess.run([sys.executable, "-m", "streamfix", "train-prior", "--help"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0
    for opt in ("--data", "--out", "--epochs", "--seed"):
        assert opt in proc.stdout


def test_clean_uses_the_prior_given_with_prior_and_refuses_a_broken_one(tmp_path, shared_data):
    import json
    import shutil

    from streamfix.prior.runtime import DEFAULT_CARD

    good, bad = tmp_path / "good", tmp_path / "bad"
    for d in (good, bad):  # user-trained models as `streamfix train-prior --out DIR` leaves them
        d.mkdir()
        for f in DEFAULT_CARD.parent.glob("canonical.*"):
            shutil.copy(f, d / f.name)
    card = json.loads((bad / "canonical.json").read_text())
    card["files"]["encoder"]["sha256"] = "0" * 64  # a user model whose graph does not match its card
    (bad / "canonical.json").write_text(json.dumps(card))
    src = shared_data / "kinect_v2" / "Ges01_wavehand.csv"

    def clean(prior):
        return subprocess.run([sys.executable, "-m", "streamfix", "clean", str(src), str(tmp_path / "out.csv"),
                               "--quiet", "--prior", str(prior)], capture_output=True, text=True, timeout=120)

    proc = clean(bad)
    assert proc.returncode == 2 and "--prior" in proc.stderr and "SHA-256" in proc.stderr
    assert not (tmp_path / "out.csv").exists()
    proc = clean(tmp_path / "missing")
    assert proc.returncode == 2 and "not found" in proc.stderr
    # a good copy loads (the full clean with it is what test_clean_cli runs with the shipped one)
    from streamfix.prior.runtime import load_default_prior, set_default_prior

    try:
        set_default_prior(good)
        assert load_default_prior().directory == good
    finally:
        set_default_prior(None)
    assert load_default_prior().directory == DEFAULT_CARD.parent


def test_training_is_deterministic_for_a_seed(shared_data):
    """`streamfix train-prior` reproduces its model: same data and seed, same weights (tiny run)."""
    import numpy as np
    import torch

    from streamfix.io.prior_takes import canonical_take
    from streamfix.prior.data import load_take
    from streamfix.prior.train import TrainConfig, train

    takes = [canonical_take(load_take(shared_data / d / f), "kinect_v2")
             for d, f in (("kinect_v2", "Ges01_wavehand.csv"), ("xia_bvh", "angry_13_000.bvh"))]
    runs = [train(takes, takes[:1], TrainConfig(epochs=1, steps_per_epoch=3, batch=4, channels=8, latent=4,
                                                workers=workers), log=lambda s: None)
            for workers in (0, 0, 2)]  # batches drawn in worker processes are the same batches
    for (m1, h1), (m2, h2) in [runs[:2], runs[::2]]:
        assert h1["train_loss"] == h2["train_loss"]
        for (k, a), b in zip(m1.state_dict().items(), m2.state_dict().values()):
            assert torch.equal(a, b), k
        assert np.isfinite(h1["held_out_loss"]).all()


def test_a_checkpoint_trained_elsewhere_exports_with_the_same_card(shared_data, tmp_path):
    """A model trained on another machine (``save_checkpoint`` there, e.g. a GPU box) is exported and carded here
    from the same weights and config: ``load_checkpoint`` returns them, and ``export_with_card`` records the
    training device and torch version of the run, not of this machine."""
    import json
    import warnings

    import torch

    from streamfix.io.prior_takes import canonical_take
    from streamfix.prior.data import load_take
    from streamfix.prior.runtime import sha256_file
    from streamfix.prior.train import TrainConfig, export_with_card, load_checkpoint, save_checkpoint, train

    takes = [canonical_take(load_take(shared_data / "kinect_v2" / "Ges01_wavehand.csv"), "kinect_v2")]
    cfg = TrainConfig(epochs=1, steps_per_epoch=2, batch=4, channels=8, latent=4)
    model, history = train(takes, takes, cfg, log=lambda s: None)
    cfg.device = "cuda:0"  # as a GPU run's config records it
    save_checkpoint(model, history, cfg, tmp_path / "run.pt")
    loaded, hist2, cfg2 = load_checkpoint(tmp_path / "run.pt")
    assert cfg2.as_dict() == cfg.as_dict() and hist2["train_loss"] == history["train_loss"]
    for (k, a), b in zip(model.state_dict().items(), loaded.state_dict().values()):
        assert torch.equal(a, b), k
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        card = export_with_card(loaded, hist2, takes, [], tmp_path / "out", cfg2, log=lambda s: None, evaluate=False)
    on_disk = json.loads((tmp_path / "out" / "canonical.json").read_text())
    assert on_disk["training"]["device"] == "cuda:0" and on_disk["training"]["torch"] == history["torch"]
    assert on_disk["latent"] == 4 and on_disk["channels"] == 8 and card["files"] == on_disk["files"]
    for entry in on_disk["files"].values():
        assert sha256_file(tmp_path / "out" / entry["file"]) == entry["sha256"]
    assert (tmp_path / "out" / "canonical.md").read_text().count("cuda") == 1


def test_source_shares_decide_where_batches_come_from():
    """``TrainConfig.shares`` / ``--share``: a source's share of the draws follows its weight, any number of takes."""
    import numpy as np

    from streamfix.prior.data import Take, source_weights

    def take(name: str, source: str, frames: int) -> Take:
        return Take(name, np.zeros((frames, 20, 3)), np.ones((frames, 20), bool), 30.0, source)

    takes = [take("a", "bvh", 30), take("b", "uiprmd_vicon", 300), take("c", "uiprmd_vicon", 600)]
    p = source_weights(takes, {"bvh": 0.75, "uiprmd_vicon": 0.25})
    np.testing.assert_allclose(p, [0.75, 0.25 / 3, 0.5 / 3])
    assert source_weights(takes, {"bvh": 0.0, "uiprmd_vicon": 1.0})[0] == 0.0


def _shipped_card_copy(tmp_path):
    """The shipped model copied to ``tmp_path/model`` with one held-out take (keeps a rescore short):
    (directory, card path, card dict; the card not yet written back)."""
    import json
    import shutil

    from streamfix.prior.runtime import DEFAULT_CARD

    model = tmp_path / "model"
    model.mkdir()
    for f in DEFAULT_CARD.parent.glob("canonical.*"):
        shutil.copy(f, model / f.name)
    card_path = model / "canonical.json"
    card = json.loads(card_path.read_text())
    card["training"]["held_out"] = ["131_02"]
    return model, card_path, card


def test_rescore_rewrites_the_held_out_scores_of_an_exported_card(tmp_path, shared_data):
    import json

    from streamfix.evaluation.occlusion import score_prior_on_takes
    from streamfix.io.prior_takes import canonical_takes
    from streamfix.prior.data import split_takes
    from streamfix.prior.runtime import Prior

    model, card_path, card = _shipped_card_copy(tmp_path)
    card["held_out_scores"] = [{"take": "stale", "pattern": "random", "test_otp": 50.0, "method": "prior_latent",
                                "rmse_m": 9.0, "rmse_dropped_m": 9.0, "windows": 1, "time_ms": 0.0}]
    card["held_out_protocol"] = "an older protocol"
    card_path.write_text(json.dumps(card))
    proc = subprocess.run([sys.executable, "-m", "streamfix", "train-prior", "--data", str(shared_data),
                           "--rescore", str(card_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    new = json.loads(card_path.read_text())
    _, held = split_takes(canonical_takes(shared_data, kinect_v1=True), ("131_02",))
    want = score_prior_on_takes(card_path, held, seed=card["training"]["config"]["seed"])
    untimed = lambda recs: [{k: v for k, v in r.items() if k != "time_ms"} for r in recs]  # noqa: E731
    assert untimed(new["held_out_scores"]) == untimed(want)
    assert {r["take"] for r in new["held_out_scores"]} == {"131_02"}
    assert "MIRROR_ENSEMBLE" in new["held_out_protocol"]
    assert new["files"] == card["files"]  # the graphs are untouched and still load against the card
    Prior.load(card_path)
    md = (model / "canonical.md").read_text()
    assert "| 131_02 | random | 50 |" in md and "stale" not in md

    card["training"]["held_out"] = ["no_such_take"]
    card_path.write_text(json.dumps(card))
    proc = subprocess.run([sys.executable, "-m", "streamfix", "train-prior", "--data", str(shared_data),
                           "--rescore", str(card_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    assert "no_such_take" in proc.stderr and "Traceback" not in proc.stderr


def test_int8_jacobian_converts_an_exported_card_once_and_refuses_a_mismatched_graph(tmp_path, shared_data):
    """``train-prior --int8-jacobian CARD``: the shipped card is int8 already (the graph stays as it is, the card
    is rescored); a graph that does not match its card is refused, not re-hashed."""
    import json

    from streamfix.prior.runtime import Prior

    model, card_path, card = _shipped_card_copy(tmp_path)
    card_path.write_text(json.dumps(card))
    cmd = [sys.executable, "-m", "streamfix", "train-prior", "--data", str(shared_data), "--int8-jacobian", str(card_path)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    new = json.loads(card_path.read_text())
    assert new["files"] == card["files"] and new["files"]["decoder_jacobian"]["tangent_products"] == "int8"
    assert {r["take"] for r in new["held_out_scores"]} == {"131_02"}
    Prior.load(card_path)
    graph = model / card["files"]["decoder_jacobian"]["file"]
    graph.write_bytes(graph.read_bytes() + b"\0")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "does not match" in proc.stderr and "Traceback" not in proc.stderr
    assert json.loads(card_path.read_text())["files"] == card["files"]
    proc = subprocess.run(cmd + ["--rescore", str(card_path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "not both" in proc.stderr
