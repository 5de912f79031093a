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


def test_streamfix_live_is_the_causal_live_topic(shared_data):
    """``streamfix_live`` scores serve's ``live`` topic: frame t's output does not depend on
    any later frame (the ``clean`` methods look 0.5 s ahead, so theirs does)."""
    import numpy as np

    from streamfix.evaluation.registry import run_method
    from streamfix.io import read_motion

    m = read_motion(shared_data / "kinect_v2" / "Ges03_drawlines.csv")
    x = m.positions[:150].copy()
    conf = m.confidence[:150]
    later = x.copy()
    later[100:] += np.array([0.3, -0.2, 0.1])  # the body jumps after frame 99
    args = (conf, m.skeleton.bone_array, m.rate_hz)

    def run(method, positions):
        return run_method(method, positions, *args, skeleton=m.skeleton)

    live, live_later = run("streamfix_live", x), run("streamfix_live", later)
    assert np.array_equal(live[:100], live_later[:100], equal_nan=True)
    clean, clean_later = run("streamfix_serve", x), run("streamfix_serve", later)
    assert not np.allclose(clean[80:100], clean_later[80:100])
