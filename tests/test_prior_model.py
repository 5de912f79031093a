"""The shipped canonical-body prior: it loads without torch, its card describes it, and D(z*) does what Eq. 1 says."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from streamfix.canonical import CANONICAL_BONES, CANONICAL_JOINTS, LAYOUTS
from streamfix.evaluation.occlusion import drop_masks, nearest_joint_fill
from streamfix.io.prior_takes import canonical_take
from streamfix.prior.data import HELD_OUT, cut_windows, load_take, resample_masked
from streamfix.prior.init import fill_long_gaps, prior_initial_guess
from streamfix.prior.latent import fit_latent
from streamfix.prior.runtime import DEFAULT_CARD, Prior, _session, sha256_file


@pytest.fixture(scope="module")
def prior() -> Prior:
    return Prior.load()


@pytest.fixture(scope="module")
def held_out(shared_data, prior):
    """Held-out CMU take 131_02 in canonical joints at the prior's rate, as 64-frame windows with half the joints dropped."""
    take = canonical_take(load_take(shared_data / "cmu_bvh" / "131_02.bvh"), "kinect_v2")
    pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, prior.rate_hz)
    wins, masks, _ = cut_windows(pos, obs, prior.window, prior.window)
    keep = drop_masks(len(wins), 20, prior.window, "random", 50.0, np.random.default_rng(5))
    return np.nan_to_num(wins), masks, keep


def test_runtime_does_not_import_torch():
    code = (
        "import sys, numpy as np\n"
        "from streamfix.prior.runtime import Prior\n"
        "from streamfix.prior.latent import fit_latent\n"
        "from streamfix.prior.init import prior_initial_guess\n"
        "p = Prior.load()\n"
        "x = np.zeros((70, 25, 3)); o = np.ones((70, 25), bool)\n"
        "prior_initial_guess(x + np.arange(25)[None, :, None] * 0.05, o, 30.0, prior=p)\n"
        "assert 'torch' not in sys.modules, 'torch imported at run time'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_card_matches_the_shipped_graphs(prior):
    card = json.loads(DEFAULT_CARD.read_text())
    assert card["skeleton"] == "canonical" and card["joints"] == list(CANONICAL_JOINTS) and card["n_joints"] == 20
    t, j, l = card["window"], card["n_joints"], card["latent"]
    assert t % (1 << card["levels"]) == 0 and card["rate_hz"] == 30.0
    total = 0
    for role in ("encoder", "decoder", "decoder_jacobian"):
        path = DEFAULT_CARD.parent / card["files"][role]["file"]
        assert sha256_file(path) == card["files"][role]["sha256"]
        total += path.stat().st_size
        sess = _session(path, 1)
        dims = {v.name: list(v.shape) for v in list(sess.get_inputs()) + list(sess.get_outputs())}
        if role == "encoder":
            assert dims["y"] == ["batch", t, j, 3] and dims["mask"] == ["batch", t, j] and dims["z"] == ["batch", l]
        elif role == "decoder":
            assert dims["z"] == ["batch", l] and dims["x"] == ["batch", t, j, 3]
        else:
            step = card["files"][role].get("frame_step", 1)  # Jacobian rows of every step-th frame
            assert dims["jac"] == ["batch", l, t // step * j * 3] and dims["w"] == ["batch", t * j * 3]
    assert total < 5_000_000  # "a few MB" for all three together
    # every file in models/ is one the card names (nothing stale ships beside it)
    markdown = DEFAULT_CARD.with_suffix(".md")
    named = {card["files"][r]["file"] for r in card["files"]} | {DEFAULT_CARD.name, markdown.name}
    assert {p.name for p in DEFAULT_CARD.parent.iterdir() if p.is_file()} == named
    # the human-readable card is the JSON one rendered (hashes, sources, held-out rows)
    text = markdown.read_text()
    assert all(card["files"][r]["sha256"] in text for r in card["files"])
    assert all(src in text for src in card["training"]["sources"])
    assert text.count("\n| ") >= len(card["held_out_scores"]) // 3
    norm = card["normalisation"]
    assert norm["root_joint"] == "pelvis" and norm["root_index"] == CANONICAL_JOINTS.index("pelvis")
    assert np.asarray(norm["bones"]).tolist() == CANONICAL_BONES.tolist()
    assert len(norm["reference_bone_lengths_m"]) == len(CANONICAL_BONES)
    assert np.asarray(norm["facing_template"]).shape == (20, 3)
    assert set(card["layouts"]) == set(LAYOUTS)
    # the data: an hour or more, every source's licence allows commercial use, held-out people never trained on
    tr = card["training"]
    assert tr["minutes"] >= 60 and abs(sum(s["minutes"] for s in tr["sources"].values()) - tr["minutes"]) < 0.1
    for name, src in tr["sources"].items():
        assert "commercial" in src["licence"] or "PDDL" in src["licence"] or "MIT" in src["licence"] \
            or "BSD" in src["licence"], name
    assert set(tr["held_out"]) == set(HELD_OUT)
    assert {s["take"] for s in card["held_out_scores"]} == set(HELD_OUT)
    # and it runs at the card's sizes, batch dynamic
    z = prior.encode(np.zeros((3, t, j, 3)), np.ones((3, t, j)))
    assert z.shape == (3, l) and prior.decode(z).shape == (3, t, j, 3)


def test_shipped_jacobian_graph_runs_int8_tangents_within_a_few_percent_of_the_decoder(prior):
    """The card says the Jacobian graph's tangent products are 8-bit (``train.quantize_tangent_products``) and
    the graph is that: its dD/dz rows agree with central differences of the float32 decoder graph to a few per
    cent, and its D(z) is the decoder's."""
    import onnx

    entry = json.loads(DEFAULT_CARD.read_text())["files"]["decoder_jacobian"]
    graph = onnx.load(str(DEFAULT_CARD.parent / entry["file"])).graph
    assert entry.get("tangent_products") == "int8"
    assert sum(n.op_type == "MatMulInteger" for n in graph.node) == prior.card["levels"]
    rng = np.random.default_rng(4)
    t, j, l = prior.window, prior.n_joints, prior.latent_size
    step = prior.jacobian_frame_step
    rows = (np.arange(t * j * 3).reshape(t, -1)[::step]).ravel()
    z = prior.encode(rng.normal(0, 0.2, (2, t, j, 3)), np.ones((2, t, j))).astype(np.float64)
    x, jac = prior.decode_with_jacobian(z)
    np.testing.assert_allclose(x, prior.decode(z), atol=1e-5, rtol=0)
    h = 1e-3  # the decoder is piecewise linear (ReLU): central differences are exact but for the kinks they cross
    eye = np.eye(l) * h
    fd = np.stack([(prior.decode(zb + eye).reshape(l, -1) - prior.decode(zb - eye).reshape(l, -1)) / (2 * h)
                   for zb in z])[:, :, rows]
    err = np.linalg.norm(jac - fd, axis=(1, 2)) / np.linalg.norm(fd, axis=(1, 2))
    assert (err < 0.05).all(), err


def test_a_tampered_graph_is_refused(tmp_path):
    card = json.loads(DEFAULT_CARD.read_text())
    for role in ("encoder", "decoder", "decoder_jacobian"):
        (tmp_path / card["files"][role]["file"]).write_bytes((DEFAULT_CARD.parent / card["files"][role]["file"]).read_bytes())
    card["files"]["decoder"]["sha256"] = "0" * 64
    (tmp_path / "canonical.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match="SHA-256"):
        Prior.load(tmp_path)


@pytest.mark.parametrize("tol", [0.0, 0.02])
def test_latent_fit_never_moves_observed_joints_beyond_the_tolerance(prior, held_out, tol):
    wins, masks, keep = held_out
    obs = masks[:2] & keep[:2]
    fit = fit_latent(prior, wins[:2], obs, fit_tol_m=tol)
    dist = np.linalg.norm(fit.positions - wins[:2], axis=-1)[obs]
    assert dist.max() <= tol + 1e-9
    # the decoder alone does not fit them exactly, so the tolerance is what holds them
    assert np.linalg.norm(fit.decoded - wins[:2], axis=-1)[obs].max() > tol
    # unobserved joints come from the decoder
    np.testing.assert_array_equal(fit.positions[~obs], fit.decoded[~obs])
    # LM only accepts descent steps: the fit of Eq. (1) is never worse than z(0) = E(Y)
    assert np.all(fit.fit_rms_m <= fit.initial_rms_m + 1e-12)


def test_latent_optimisation_beats_the_feed_forward_pass(prior, held_out):
    wins, masks, keep = held_out
    obs = masks & keep
    dropped = masks & ~keep
    enc = prior.reconstruct(wins, obs)
    lat = fit_latent(prior, wins, obs).decoded
    nearest = np.stack([nearest_joint_fill(w, o, CANONICAL_BONES) for w, o in zip(wins, obs)])
    rmse = lambda x: np.sqrt(((x - wins) ** 2).sum(-1)[dropped].mean())  # noqa: E731
    assert rmse(lat) < rmse(enc)
    assert rmse(lat) < rmse(nearest)


@pytest.mark.parametrize("n_frames,rate", [(40, 30.0), (150, 30.0), (400, 120.0)])
def test_initial_guess_handles_any_length_and_rate(prior, shared_data, n_frames, rate):
    take = load_take(shared_data / "cmu_bvh" / "131_02.bvh")
    pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, rate)
    pos, obs = np.nan_to_num(pos[:n_frames]), obs[:n_frames].copy()
    obs[:, [9, 10, 11, 23, 24]] = False  # right forearm and hand missing throughout
    guess = prior_initial_guess(pos, obs, rate, prior=prior)
    assert guess.shape == pos.shape and np.isfinite(guess).all()
    np.testing.assert_array_equal(guess[obs], pos[obs])
    err = np.linalg.norm(guess - pos, axis=-1)[~obs]
    assert np.median(err) < 0.5  # in the body's vicinity, not at the origin or the sensor


def test_fill_long_gaps_fills_only_long_gaps_and_meets_the_ends(prior, shared_data):
    take = load_take(shared_data / "cmu_bvh" / "131_02.bvh")
    pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, 30.0)
    pos, obs = np.nan_to_num(pos[:120]), obs[:120].copy()
    obs[20:60, 7] = False  # 40-frame gap: long
    obs[80:84, 7] = False  # 4-frame gap: short, left to the solver
    obs[100:, 3] = False  # trailing gap
    filled, rec = fill_long_gaps(pos, obs, 30.0, min_gap_frames=15, prior=prior)
    assert rec[20:60, 7].all() and rec[100:, 3].all()
    assert not rec[80:84, 7].any() and np.isnan(filled[80:84, 7]).all()
    assert rec.sum() == 40 + 20
    np.testing.assert_array_equal(filled[obs], pos[obs])
    # the fill joins the observed samples: its first/last values are a frame's motion away
    step = np.linalg.norm(np.diff(pos[:, 7], axis=0), axis=-1).max()
    assert np.linalg.norm(filled[20, 7] - pos[19, 7]) < step + 0.03
    assert np.linalg.norm(filled[59, 7] - pos[60, 7]) < step + 0.03


def test_solver_from_the_prior_needs_fewer_iterations_and_is_no_worse(prior, held_out):
    from streamfix.core.alm import solve
    from streamfix.prior.init import PRIOR_INIT_RHO_FACTOR, solver_params_for_prior_init

    wins, masks, keep = held_out
    gt, obs = wins[1], masks[1] & keep[1]
    d = np.where(obs[..., None], gt, np.nan)
    bones = CANONICAL_BONES
    alone = solve(d, obs, bones)
    params = solver_params_for_prior_init(d, obs)
    # the penalty start is the solver's own cold-start rho0 times the documented factor
    assert abs(params.rho0 / alone.state.rho0 - PRIOR_INIT_RHO_FACTOR) < 1e-6 * PRIOR_INIT_RHO_FACTOR
    init = prior_initial_guess(d, obs, prior.rate_hz, prior=prior)
    started = solve(d, obs, bones, params=params, init=init)
    assert started.converged and started.iterations <= alone.iterations / 2
    err = lambda x: np.sqrt(((x - gt) ** 2).sum(-1)[masks[1]].mean())  # noqa: E731
    assert err(started.positions) <= err(alone.positions)


def test_initial_guess_bridges_a_blackout_from_its_neighbours(prior, shared_data):
    take = load_take(shared_data / "cmu_bvh" / "131_02.bvh")
    pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, 30.0)
    pos, obs = np.nan_to_num(pos[:300]), obs[:300].copy()
    obs[100:230] = False  # the body is lost for 130 frames: some windows see nothing at all
    guess = prior_initial_guess(pos, obs, 30.0, prior=prior)
    assert np.isfinite(guess).all()
    root = guess[:, 0]
    # the blackout is bridged between the estimates around it, not sent to the sensor origin
    lo, hi = np.minimum(root[99], root[230]) - 0.3, np.maximum(root[99], root[230]) + 0.3
    assert np.all((root[100:230] >= lo) & (root[100:230] <= hi))


def test_prior_shifted_state_puts_the_prior_on_the_new_frames(prior, held_out):
    from streamfix.core.alm import solve
    from streamfix.prior.init import prior_shifted_state

    wins, masks, keep = held_out
    full = np.concatenate([wins[0], wins[1]])  # 128 consecutive frames
    fobs = np.concatenate([masks[0] & keep[0], masks[1] & keep[1]])
    bones = CANONICAL_BONES
    first = solve(np.where(fobs[:64, :, None], full[:64], np.nan), fobs[:64], bones)
    hop = 16
    d, o = full[hop:64 + hop], fobs[hop:64 + hop]
    plain = first.state.shifted(hop)
    state = prior_shifted_state(first.state, hop, d, o, 30.0, prior=prior)
    np.testing.assert_array_equal(state.A[:-hop], plain.A[:-hop])  # old frames untouched
    np.testing.assert_array_equal(state.A[-hop:][o[-hop:]], d[-hop:][o[-hop:]])  # observed new joints kept
    missing = ~o[-hop:] & masks[1][:hop]
    err = lambda a: np.linalg.norm(a[-hop:] - d[-hop:], axis=-1)[missing].mean()  # noqa: E731
    assert err(state.A) < err(plain.A)  # the prior beats constant-velocity extrapolation on the new frames
    res = solve(np.where(o[..., None], d, np.nan), o, bones, state=state)
    assert np.isfinite(res.positions).all()
