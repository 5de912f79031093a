"""The exported ONNX graphs reproduce the torch model (encoder, decoder, decoder Jacobian) to 1e-5; the shipped form
of the Jacobian graph (tangent products in 8-bit integers) keeps D(z) exact and dD/dz within a few per cent."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

torch = pytest.importorskip(
    "torch", reason="PyTorch is not installed (the optional `train` extra: pip install streamfix[train])"
)

from streamfix.prior.model import JACOBIAN_FRAME_STEP, DecoderJacobian, TemporalAutoencoder  # noqa: E402
from streamfix.prior.runtime import _session  # noqa: E402
from streamfix.prior.train import export_onnx, quantize_tangent_products, tangent_product_nodes  # noqa: E402


def _export(tmp_path_factory, int8_tangents: bool):
    torch.manual_seed(3)
    model = TemporalAutoencoder(n_joints=25, window=16, channels=8, latent=5, levels=2).eval()
    out = tmp_path_factory.mktemp("onnx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        files = export_onnx(model, out, stem="tiny", int8_tangents=int8_tangents)
    sessions = {role: _session(out / f["file"], 1) for role, f in files.items()}
    return model, sessions, files, out


@pytest.fixture(scope="module")
def tiny_exact(tmp_path_factory):
    """The exact float32 export."""
    return _export(tmp_path_factory, int8_tangents=False)


@pytest.fixture(scope="module")
def tiny(tiny_exact):
    return tiny_exact[:2]


@pytest.fixture(scope="module")
def tiny_int8(tmp_path_factory):
    """The shipped export: the Jacobian graph's tangent products in 8-bit integers."""
    return _export(tmp_path_factory, int8_tangents=True)


def _inputs(batch: int, seed: int):
    rng = np.random.default_rng(seed)
    y = rng.normal(0, 0.3, (batch, 16, 25, 3)).astype(np.float32)
    mask = (rng.random((batch, 16, 25)) > 0.4).astype(np.float32)
    return y, mask


@pytest.mark.parametrize("batch", [1, 3])  # batch dimension is dynamic
def test_encoder_decoder_match_torch(tiny, batch):
    model, s = tiny
    y, mask = _inputs(batch, batch)
    with torch.no_grad():
        z_t = model.encoder(torch.from_numpy(y), torch.from_numpy(mask)).numpy()
        x_t = model.decoder(torch.from_numpy(z_t)).numpy()
    z_o = s["encoder"].run(None, {"y": y, "mask": mask})[0]
    x_o = s["decoder"].run(None, {"z": z_t})[0]
    assert z_o.shape == (batch, 5) and x_o.shape == (batch, 16, 25, 3)
    np.testing.assert_allclose(z_o, z_t, atol=1e-5, rtol=0)
    np.testing.assert_allclose(x_o, x_t, atol=1e-5, rtol=0)


def test_encoder_ignores_values_of_unobserved_joints(tiny):
    _, s = tiny
    y, mask = _inputs(2, 7)
    y2 = y.copy()
    y2[mask == 0] += 5.0  # garbage where unobserved must not change E(Y)
    z1 = s["encoder"].run(None, {"y": y, "mask": mask})[0]
    z2 = s["encoder"].run(None, {"y": y2, "mask": mask})[0]
    np.testing.assert_allclose(z1, z2, atol=1e-6)


def _jacobian_feeds(seed: int, n: int = 16 * 25 * 3) -> dict:
    rng = np.random.default_rng(seed)
    return {"z": rng.normal(0, 1, (2, 5)).astype(np.float32), "w": (rng.random((2, n)) > 0.5).astype(np.float32),
            "y": rng.normal(0, 0.3, (2, n)).astype(np.float32), "c": rng.normal(0, 0.1, (2, 3)).astype(np.float32)}


def test_decoder_jacobian_graph_is_the_exact_jacobian(tiny):
    """The graph's ``jac`` holds the exact dD/dz rows of every JACOBIAN_FRAME_STEP-th frame; the normal equations
    are the sums over those frames times the step (what the latent fit solves)."""
    model, s = tiny
    step = JACOBIAN_FRAME_STEP
    feeds = _jacobian_feeds(1)
    z, w, y, c = (feeds[k] for k in "zwyc")
    n = w.shape[1]
    names = ["x", "jac", "r", "cost", "gram", "jtr", "h_zc"]
    out = dict(zip(names, s["decoder_jacobian"].run(names, feeds)))
    assert out["jac"].shape == (2, 5, n // step)
    rows = (np.arange(n).reshape(16, -1)[::step]).ravel()  # coordinates of the frames the rows are of
    for b in range(2):
        jt = torch.autograd.functional.jacobian(
            lambda v: model.decoder(v.unsqueeze(0)).reshape(-1), torch.from_numpy(z[b]),
            vectorize=True, strategy="forward-mode",
        ).detach().numpy()  # (N, L), autograd's own forward-mode differentiation
        np.testing.assert_allclose(out["jac"][b], jt[rows].T, atol=1e-5, rtol=0)
    with torch.no_grad():
        x_t = model.decoder(torch.from_numpy(z)).numpy()
        _, jac_j = DecoderJacobian(model.decoder, 5)(torch.from_numpy(z))
        _, jac_all = DecoderJacobian(model.decoder, 5, frame_step=1)(torch.from_numpy(z))
    np.testing.assert_allclose(out["x"], x_t, atol=1e-5, rtol=0)
    np.testing.assert_allclose(out["jac"], jac_j.numpy(), atol=1e-5, rtol=0)
    np.testing.assert_allclose(jac_all.numpy()[:, :, rows], jac_j.numpy(), atol=1e-6, rtol=0)
    # the Levenberg-Marquardt terms appended to the graph, against numpy in float64
    jac = jac_j.numpy().astype(np.float64)
    r = w * ((x_t.reshape(2, -1, 3) + c[:, None, :]).reshape(2, -1) - y)
    jw = jac * w[:, None, rows]
    np.testing.assert_allclose(out["r"], r, atol=1e-5, rtol=0)
    np.testing.assert_allclose(out["cost"], (r * r).sum(1), rtol=1e-5)
    np.testing.assert_allclose(out["gram"], step * jw @ jw.transpose(0, 2, 1), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(out["jtr"][..., 0], step * (jw * r[:, None, rows]).sum(2), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(out["h_zc"], step * jw.reshape(2, 5, -1, 3).sum(2), rtol=1e-5, atol=1e-5)


def test_int8_tangents_keep_d_of_z_exact_and_the_jacobian_within_a_few_percent(tiny_exact, tiny_int8):
    """D(z), the residual and the cost are float32 as in the exact graph; dD/dz carries the int8 rounding only
    (a few per cent, Frobenius); the normal equations are the graph's own Jacobian summed as before."""
    _, exact, exact_files, exact_dir = tiny_exact
    _, quant, files, out_dir = tiny_int8
    assert files["decoder_jacobian"]["tangent_products"] == "int8"
    assert "tangent_products" not in exact_files["decoder_jacobian"]
    names = ["x", "jac", "r", "cost", "gram", "jtr", "h_zc"]
    step = JACOBIAN_FRAME_STEP
    rows = (np.arange(16 * 25 * 3).reshape(16, -1)[::step]).ravel()
    for seed in range(3):
        feeds = _jacobian_feeds(seed)
        e = dict(zip(names, exact["decoder_jacobian"].run(names, feeds)))
        q = dict(zip(names, quant["decoder_jacobian"].run(names, feeds)))
        for name in ("x", "r", "cost"):
            np.testing.assert_allclose(q[name], e[name], atol=1e-5, rtol=1e-6)
        err = np.linalg.norm(q["jac"] - e["jac"], axis=(1, 2)) / np.linalg.norm(e["jac"], axis=(1, 2))
        assert (err < 0.06).all() and (err > 0).all(), err  # quantised, and close
        jw = q["jac"].astype(np.float64) * feeds["w"][:, None, rows]
        np.testing.assert_allclose(q["gram"], step * jw @ jw.transpose(0, 2, 1), rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(q["jtr"][..., 0], step * (jw * q["r"][:, None, rows]).sum(2), rtol=1e-4, atol=1e-5)
    # the encoder and decoder graphs are not touched
    for role in ("encoder", "decoder"):
        assert (out_dir / files[role]["file"]).read_bytes() == (exact_dir / files[role]["file"]).read_bytes()


def test_tangent_products_are_found_by_structure_and_quantised_once(tmp_path_factory):
    """One product per layer of the tangents (the decoder's two transposed convolutions here), none of D(z)'s own
    products and none of the normal equations'; quantising a quantised graph again leaves it as it is."""
    import onnx

    _, _, files, out_dir = _export(tmp_path_factory, int8_tangents=False)
    path = out_dir / files["decoder_jacobian"]["file"]
    graph = onnx.load(str(path)).graph
    nodes = tangent_product_nodes(graph)
    matmuls = [n for n in graph.node if n.op_type == "MatMul"]
    inits = {t.name for t in graph.initializer}
    assert len(nodes) == 2 and len([n for n in matmuls if any(i in inits for i in n.input)]) == 4
    assert quantize_tangent_products(path) == nodes
    before = path.read_bytes()
    assert quantize_tangent_products(path) == [] and path.read_bytes() == before
    assert sum(n.op_type == "MatMulInteger" for n in onnx.load(str(path)).graph.node) == 2


def test_quantize_card_jacobian_rewrites_the_card_of_a_float_export(tmp_path_factory):
    """An exported card with the float Jacobian graph gets the int8 one, its hash and the flag; D(z) unchanged."""
    import json

    from streamfix.prior.runtime import sha256_file
    from streamfix.prior.train import quantize_card_jacobian

    _, sessions, files, out_dir = _export(tmp_path_factory, int8_tangents=False)
    card_path = out_dir / "tiny.json"
    card_path.write_text(json.dumps({"files": files}))
    entry = quantize_card_jacobian(card_path)
    assert json.loads(card_path.read_text())["files"]["decoder_jacobian"] == entry
    assert entry["tangent_products"] == "int8" and entry["sha256"] == sha256_file(out_dir / entry["file"])
    assert entry["sha256"] != files["decoder_jacobian"]["sha256"]
    feeds = _jacobian_feeds(5)
    x_new = _session(out_dir / entry["file"], 1).run(["x"], feeds)[0]
    np.testing.assert_allclose(x_new, sessions["decoder_jacobian"].run(["x"], feeds)[0], atol=1e-5, rtol=0)


def test_reexport_gives_matmul_graphs_with_the_same_outputs(tmp_path):
    """A card whose decoder graphs are the convolutional export gets MatMul-form graphs with the same outputs."""
    import json

    from streamfix.prior.train import reexport_decoder_graphs

    torch.manual_seed(5)
    model = TemporalAutoencoder(n_joints=25, window=16, channels=8, latent=5, levels=2).eval()
    z = torch.zeros(2, 5)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        # the convolutional graphs as exported before (named weights), written by torch directly
        torch.onnx.export(model.decoder, (z,), str(tmp_path / "m.decoder.onnx"), input_names=["z"], output_names=["x"],
                          dynamic_axes={"z": {0: "batch"}, "x": {0: "batch"}}, opset_version=17, dynamo=False)
    old = _session(tmp_path / "m.decoder.onnx", 1)
    card = {"n_joints": 25, "window": 16, "channels": 8, "latent": 5, "levels": 2,
            "files": {"decoder": {"file": "m.decoder.onnx"}, "decoder_jacobian": {"file": "m.decoder_jacobian.onnx"}}}
    (tmp_path / "m.json").write_text(json.dumps(card))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        files = reexport_decoder_graphs(tmp_path / "m.json", int8_tangents=False)
    saved = json.loads((tmp_path / "m.json").read_text())["files"]
    assert saved == files and all(len(f["sha256"]) == 64 for f in files.values())
    zs = np.random.default_rng(2).normal(0, 1, (3, 5)).astype(np.float32)
    new = _session(tmp_path / "m.decoder.onnx", 1)
    np.testing.assert_allclose(new.run(None, {"z": zs})[0], old.run(None, {"z": zs})[0], atol=1e-6, rtol=0)
    jac = _session(tmp_path / "m.decoder_jacobian.onnx", 1)
    n = 16 * 25 * 3
    feeds = {"z": zs, "w": np.ones((3, n), np.float32), "y": np.zeros((3, n), np.float32), "c": np.zeros((3, 3), np.float32)}
    x, j = jac.run(["x", "jac"], feeds)
    with torch.no_grad():
        _, j_t = DecoderJacobian(model.decoder, 5)(torch.from_numpy(zs))
    np.testing.assert_allclose(x, old.run(None, {"z": zs})[0], atol=1e-6, rtol=0)
    np.testing.assert_allclose(j, j_t.numpy(), atol=1e-5, rtol=0)
    # a MatMul-form graph has no named weights left: re-exporting it again says what to do instead
    with pytest.raises(ValueError, match="checkpoint"):
        reexport_decoder_graphs(tmp_path / "m.json")
