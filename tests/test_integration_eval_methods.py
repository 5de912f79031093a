"""``streamfix eval`` accepts the occlusion / long-gap protocols' own method names."""
from __future__ import annotations

import json

from streamfix.cli import main
from streamfix.evaluation.registry import ALL_METHODS


def test_all_methods_lists_protocol_methods():
    from streamfix.evaluation import occlusion

    assert set(occlusion.METHODS) <= set(ALL_METHODS)
    try:
        from streamfix.evaluation import long_gaps
    except ModuleNotFoundError:
        return
    assert set(long_gaps.METHODS) <= set(ALL_METHODS)


def test_eval_occlusion_accepts_prior_latent(shared_data, capsys):
    path = shared_data / "kinect_v2" / "Ges01_wavehand.csv"
    code = main(["eval", str(path), "--protocol", "occlusion", "--methods", "prior_latent", "--levels", "50", "--json"])
    assert code == 0
    recs = json.loads(capsys.readouterr().out)
    assert recs and {r["method"] for r in recs} == {"prior_latent"}
    assert all(r["protocol"] == "occlusion" and r["rmse_m"] >= 0 for r in recs)
