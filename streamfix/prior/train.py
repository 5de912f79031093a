"""Train the temporal autoencoder prior and export it to ONNX (torch; offline only).

Training follows Lohit et al. Sec. 4.2 (the "ambient" autoencoder): the training windows
are themselves partially observed (Kinect: tracked joints only; padding of short
takes), the encoder sees a further randomly dropped subset (``data.drop_joints``), and
the loss is the masked Euclidean loss over the joint-frames the *data* observed:

    L(Y, X^) = sum_n sum_j m_nj || Y_nj - X^_nj ||^2 / (3 sum m)                (Sec. 4.2)

with X^ = D(E(A'Y)) (A' = the extra drop). AdamW (lr 2e-3, divided by 10 after 75 %
and 90 % of the steps, as in the paper's Appendix A.1, scaled to our epochs).

Deterministic for a seed: numpy ``Generator((seed, k))`` draws batch k's windows and masks
(whichever process draws it), ``torch.manual_seed(seed)`` the weights and the input noise,
one torch thread on the CPU. ``TrainConfig.device="cuda"`` trains the same batches on a GPU
(weights equal up to float rounding); ``workers`` draws batches in parallel processes.
"""
from __future__ import annotations

import json
import time
from collections import deque
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from streamfix.canonical import CANONICAL_BONES, CANONICAL_HIPS, CANONICAL_JOINTS, CANONICAL_SCALE_BONES, LAYOUTS
from streamfix.io.prior_takes import canonical_takes

from .data import (
    CANONICAL_NORM,
    HELD_OUT,
    SOURCE_SHARES,
    MODEL_RATE_HZ,
    Take,
    cut_windows,
    facing_template,
    make_batch,
    mean_bone_lengths,
    resample_masked,
    split_takes,
)
from .model import JACOBIAN_FRAME_STEP, JACOBIAN_INT8_TANGENTS, DecoderJacobian, DecoderMatmul, TemporalAutoencoder
from .normalize import apply_norm, normalise
from .runtime import sha256_file

__all__ = ["TrainConfig", "train", "export_onnx", "held_out_windows", "train_and_export", "export_with_card",
           "rescore_card", "save_checkpoint", "load_checkpoint", "HELD_OUT_PROTOCOL", "quantize_tangent_products",
           "quantize_card_jacobian"]


class TrainConfig:
    """Hyper-parameters (sizes scaled down from the paper's HDM05 model). The held-out loss was
    still falling at 100 epochs (the learning rate drops at 75 % and 90 % of the steps); the
    shipped model's card records its epochs and training time.

    ``shares`` is each source's share of a batch (``data.SOURCE_SHARES`` by default). ``device``
    ("cpu", "cuda") and ``workers`` (processes drawing batches beside the training loop) change
    speed only: batch k is drawn from its own generator ``Generator((seed, k))``, so the batches
    are the same for any number of workers, and the weights differ between devices by float
    rounding alone."""

    def __init__(
        self,
        epochs: int = 600,
        seed: int = 0,
        window: int = 64,
        channels: int = 96,
        latent: int = 32,
        levels: int = 4,
        batch: int = 64,
        steps_per_epoch: int = 60,
        lr: float = 2e-3,
        threads: int = 1,
        weight_decay: float = 0.01,
        input_noise: float = 0.01,
        proportion_sigma: float = 0.08,
        shares: dict[str, float] | None = None,
        device: str = "cpu",
        workers: int = 0,
    ):
        self.weight_decay, self.input_noise = weight_decay, input_noise
        self.proportion_sigma = proportion_sigma
        self.epochs, self.seed, self.window = epochs, seed, window
        self.channels, self.latent, self.levels = channels, latent, levels
        self.batch, self.steps_per_epoch, self.lr, self.threads = batch, steps_per_epoch, lr, threads
        self.shares = dict(SOURCE_SHARES if shares is None else shares)
        self.device, self.workers = device, workers

    def as_dict(self) -> dict:
        return dict(vars(self))


class _Batches:
    """The training batches in order: batch k from ``Generator((seed, k))``, drawn in this process
    or, with ``workers`` > 0, by forked worker processes a bounded number of batches ahead."""

    def __init__(self, takes: list[Take], config: TrainConfig, bones: np.ndarray, ref: np.ndarray, template: np.ndarray):
        self._args = (takes, config, bones, ref, template)
        self._pool = None
        if config.workers > 0:
            import multiprocessing

            global _WORKER_ARGS
            _WORKER_ARGS = self._args  # inherited by the forked workers
            self._pool = multiprocessing.get_context("fork").Pool(config.workers)

    def __iter__(self):
        total = self._args[1].epochs * self._args[1].steps_per_epoch
        if self._pool is None:
            for k in range(total):
                yield _draw_batch(k, self._args)
            return
        ahead = 4 * self._args[1].workers
        pending = deque(self._pool.apply_async(_worker_batch, (k,)) for k in range(min(ahead, total)))
        for k in range(total):
            if k + ahead < total:
                pending.append(self._pool.apply_async(_worker_batch, (k + ahead,)))
            yield pending.popleft().get()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool = None


_WORKER_ARGS: tuple | None = None


def _draw_batch(k: int, args: tuple) -> tuple[np.ndarray, ...]:
    takes, config, bones, ref, template = args
    rng = np.random.default_rng((config.seed, k))
    return make_batch(takes, rng, config.batch, bones, ref, config.window, template=template, shares=config.shares,
                      proportion_sigma=config.proportion_sigma)


def _worker_batch(k: int) -> tuple[np.ndarray, ...]:
    return _draw_batch(k, _WORKER_ARGS)


def held_out_windows(
    takes: list[Take], bones: np.ndarray, ref: np.ndarray, window: int, drop_fraction: float, seed: int,
    template: np.ndarray | None = None,
) -> tuple[np.ndarray, ...]:
    """Fixed evaluation windows of the held-out takes at 30 Hz (hop window/2), a random
    ``drop_fraction`` of joints dropped for each whole window; normalised like ``make_batch``.
    Returns (y_in, m_in, y_target, m_target, scale) as float32 arrays (scale: (W,) metres per unit)."""
    rng = np.random.default_rng(seed)
    ys, ms, yt, mt, sc = [], [], [], [], []
    for take in takes:
        pos, obs = resample_masked(take.positions, take.observed, take.rate_hz, MODEL_RATE_HZ)
        wp, wm, _ = cut_windows(pos, obs, window, window // 2)
        n_j = wp.shape[2]
        for p, m in zip(wp, wm):  # windows
            keep = m.copy()
            keep[:, rng.choice(n_j, size=int(round(drop_fraction * n_j)), replace=False)] = False
            yi, norm = normalise(p, keep, bones, ref, template=template, **CANONICAL_NORM)
            ys.append(yi)
            ms.append(keep)
            yt.append(np.where(m[..., None], apply_norm(np.nan_to_num(p), norm), 0.0))
            mt.append(m)
            sc.append(norm.scale)
    f = np.float32
    return (np.asarray(ys, f), np.asarray(ms, f), np.asarray(yt, f), np.asarray(mt, f), np.asarray(sc, f))


def _masked_loss(x: torch.Tensor, y: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """Sec. 4.2 masked loss: mean squared error over observed coordinates."""
    return (((x - y) ** 2) * m.unsqueeze(-1)).sum() / (3.0 * m.sum().clamp(min=1.0))


def train(
    train_takes: list[Take],
    test_takes: list[Take],
    config: TrainConfig,
    log: Callable[[str], None] = print,
) -> tuple[TemporalAutoencoder, dict]:
    """Train on ``train_takes``; print progress and the held-out loss each epoch; return (model, history)."""
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    gen = torch.Generator().manual_seed(config.seed)
    device = torch.device(config.device)
    bones = CANONICAL_BONES
    ref = mean_bone_lengths(train_takes, bones)
    template = facing_template(train_takes, bones, ref)
    batches = _Batches(train_takes, config, bones, ref, template)  # workers fork before the device is touched
    model = TemporalAutoencoder(len(CANONICAL_JOINTS), config.window, config.channels, config.latent, config.levels)
    model.to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    total = config.epochs * config.steps_per_epoch
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, [int(0.75 * total), int(0.9 * total)], gamma=0.1)
    # every 4th held-out take with a ground truth (not Kinect v1): enough to follow the held-out loss
    monitor = [t for t in test_takes if t.source != "uiprmd_kinect_v1"][::4]
    held = held_out_windows(monitor, bones, ref, config.window, 0.5, config.seed + 1, template) if monitor else None
    history: dict = {"epoch": [], "train_loss": [], "held_out_loss": [], "held_out_rmse_dropped_m": []}
    t_start = time.perf_counter()
    stream = iter(batches)
    try:
        for epoch in range(1, config.epochs + 1):
            model.train()
            losses = []
            for _ in range(config.steps_per_epoch):
                yi, mi, yt, mt = (torch.from_numpy(a) for a in next(stream))
                if config.input_noise > 0:  # sensor-like jitter on the encoder's input only (normalised units ~ m)
                    yi = yi + config.input_noise * torch.randn(yi.shape, generator=gen) * mi.unsqueeze(-1)
                yi, mi, yt, mt = (a.to(device) for a in (yi, mi, yt, mt))
                loss = _masked_loss(model(yi, mi), yt, mt)
                opt.zero_grad()
                loss.backward()
                opt.step()
                sched.step()
                losses.append(loss.detach())
            train_loss = float(torch.stack(losses).mean())
            msg = f"epoch {epoch:3d}/{config.epochs}  train loss {train_loss:.5f}"
            history["epoch"].append(epoch)
            history["train_loss"].append(train_loss)
            if held is not None and len(held[0]):
                model.eval()
                with torch.no_grad():
                    yi, mi, yt, mt, sc = (torch.from_numpy(a).to(device) for a in held)
                    x = model(yi, mi)
                    hl = float(_masked_loss(x, yt, mt))
                    dropped = (mt > 0) & (mi == 0)
                    err2 = ((x - yt) ** 2).sum(-1) * sc[:, None, None] ** 2
                    rmse = float(torch.sqrt(err2[dropped].mean())) if dropped.any() else float("nan")
                history["held_out_loss"].append(hl)
                history["held_out_rmse_dropped_m"].append(rmse)
                msg += f"  held-out loss {hl:.5f}  held-out D(E(Y)) RMSE on dropped joints (OTP 50%) {100 * rmse:.2f} cm"
            log(msg + f"  [{time.perf_counter() - t_start:.0f} s]")
    finally:
        batches.close()
    model.to("cpu")
    history["seconds"] = round(time.perf_counter() - t_start, 1)
    history["torch"] = torch.__version__
    history["reference_bone_lengths_m"] = ref.tolist()
    history["facing_template"] = np.round(template, 5).tolist()
    return model, history


def export_onnx(model: TemporalAutoencoder, out_dir: str | Path, stem: str = "canonical",
                int8_tangents: bool = JACOBIAN_INT8_TANGENTS) -> dict[str, dict]:
    """Export encoder, decoder and decoder-Jacobian with the legacy exporter (``dynamo=False``), batch dynamic.

    The decoder graphs use the time-major MatMul form (``model.DecoderMatmul``): the same
    values as the convolutional decoder, faster in onnxruntime on one core.
    ``int8_tangents``: the Jacobian graph's tangent products in 8-bit integers
    (``quantize_tangent_products``); False keeps the exact float32 Jacobian.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model = model.eval()
    cfg = model.config
    t, j, l = cfg["window"], cfg["n_joints"], cfg["latent"]
    y = torch.zeros(2, t, j, 3)
    m = torch.ones(2, t, j)
    z = torch.zeros(2, l)
    files = {}
    specs = {
        "encoder": (model.encoder, (y, m), ["y", "mask"], ["z"]),
        "decoder": (DecoderMatmul(model.decoder), (z,), ["z"], ["x"]),
        "decoder_jacobian": (DecoderJacobian(model.decoder, l), (z,), ["z"], ["x", "jac"]),
    }
    for role, (module, args, inputs, outputs) in specs.items():
        path = out_dir / f"{stem}.{role}.onnx"
        dyn = {name: {0: "batch"} for name in inputs + outputs}
        with torch.no_grad():
            torch.onnx.export(
                module, args, str(path), input_names=inputs, output_names=outputs,
                dynamic_axes=dyn, opset_version=17, dynamo=False,
            )
        if role == "decoder_jacobian":
            inputs, outputs = add_gram_output(path, l, t * j * 3, t, JACOBIAN_FRAME_STEP)
        files[role] = {"file": path.name, "sha256": sha256_file(path), "inputs": inputs, "outputs": outputs}
        if role == "decoder_jacobian":
            files[role]["frame_step"] = JACOBIAN_FRAME_STEP
            if int8_tangents:
                _quantize_entry(path, files[role])
    torch.save({"config": cfg, "state_dict": model.state_dict()}, out_dir / f"{stem}.pt")  # for re-export, not shipped
    return files


def reexport_decoder_graphs(card_path: str | Path, int8_tangents: bool = JACOBIAN_INT8_TANGENTS) -> dict[str, dict]:
    """Export a card's ``decoder`` and ``decoder_jacobian`` again in the current graph form, from their own weights.

    The weights are read from the card's decoder graph (no torch checkpoint needed), so the
    model is unchanged (outputs agree to float rounding) while the graphs pick up faster
    operator forms (``model.DecoderMatmul``); the card's hashes and rendered ``.md`` (when there
    is one) are rewritten. The encoder graph is left as it is. Returns the new ``files`` entries.
    ``int8_tangents`` as ``export_onnx``.
    Reads graphs whose weights are named initialisers (the convolutional form exported before;
    the MatMul form folds them, so re-export those from the training checkpoint with ``export_onnx``).
    """
    import onnx
    from onnx import numpy_helper

    from .model import Decoder

    card_path = Path(card_path)
    card = json.loads(card_path.read_text())
    directory = card_path.parent
    graph = onnx.load(str(directory / card["files"]["decoder"]["file"])).graph
    weights = {t.name: torch.from_numpy(numpy_helper.to_array(t).copy()) for t in graph.initializer}
    decoder = Decoder(int(card["n_joints"]), int(card["window"]), int(card["channels"]), int(card["latent"]),
                      int(card["levels"]))
    missing = [k for k in decoder.state_dict() if k not in weights]
    if missing:
        raise ValueError(f"{card['files']['decoder']['file']}: weights {missing} are not named in the graph (a graph "
                         "exported in the MatMul form folds them); re-export from the training checkpoint with export_onnx")
    state = {k: weights[k] for k in decoder.state_dict()}
    decoder.load_state_dict(state)
    decoder.eval()
    z = torch.zeros(2, int(card["latent"]))
    specs = {"decoder": (DecoderMatmul(decoder), ["x"]),
             "decoder_jacobian": (DecoderJacobian(decoder, int(card["latent"])), ["x", "jac"])}
    for role, (module, outputs) in specs.items():
        path = directory / card["files"][role]["file"]
        dyn = {name: {0: "batch"} for name in ["z"] + outputs}
        with torch.no_grad():
            torch.onnx.export(module, (z,), str(path), input_names=["z"], output_names=outputs,
                              dynamic_axes=dyn, opset_version=17, dynamo=False)
        inputs = ["z"]
        if role == "decoder_jacobian":
            inputs, outputs = add_gram_output(path, int(card["latent"]), int(card["window"]) * int(card["n_joints"]) * 3,
                                              int(card["window"]), JACOBIAN_FRAME_STEP)
        card["files"][role] = {"file": path.name, "sha256": sha256_file(path), "inputs": inputs, "outputs": outputs}
        if role == "decoder_jacobian":
            card["files"][role]["frame_step"] = JACOBIAN_FRAME_STEP
            if int8_tangents:
                _quantize_entry(path, card["files"][role])
    card_path.write_text(json.dumps(card, indent=1))
    if card_path.with_suffix(".md").is_file():
        write_card_markdown(card, card_path.with_suffix(".md"))
    return card["files"]


def tangent_product_nodes(graph) -> list[str]:
    """Names of the MatMul nodes of an exported decoder-Jacobian ``graph`` (onnx GraphProto) that multiply the
    forward-mode tangents by a layer's weights.

    The tangents start from the fully connected layer's weight matrix W (``model.DecoderJacobian``: the
    rows of W^T, gated), read by anything but that layer's own Gemm, or from the copy of W^T the exporter
    folds into an initialiser; every tensor computed from them is a tangent, and a MatMul of a tangent
    with an initialiser is one of the products. D(z)'s own products read no tangent, and the normal
    equations' products (``add_gram_output``) have no initialiser.
    """
    from onnx import numpy_helper

    arrays = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    gemm = next(n for n in graph.node if n.op_type == "Gemm")
    w_t = arrays[gemm.input[1]].T
    tangents = {gemm.input[1]} | {name for name, a in arrays.items()
                                  if a.size == w_t.size and a.squeeze().shape == w_t.shape and np.array_equal(a.squeeze(), w_t)}
    inits = set(arrays)
    names = []
    for node in graph.node:  # topological order
        if node is gemm or not tangents.intersection(node.input):
            continue
        tangents.update(node.output)
        if node.op_type == "MatMul" and any(i in inits for i in node.input):
            names.append(node.name)
    return names


def quantize_tangent_products(path: str | Path) -> list[str]:
    """Run a decoder-Jacobian graph's tangent products in 8-bit integers, in place; returns the nodes changed.

    The products of the L tangents with each layer's weights (``tangent_product_nodes``) are most
    of the graph's cost on one core. They become onnxruntime's dynamic quantisation
    (``MatMulInteger``: weights int8 per output channel, tangents uint8 with one scale per call),
    which costs less. dD/dz then carries a few per cent of rounding error (relative,
    Frobenius); D(z), the residual r and the cost stay float32. The Jacobian only steers the
    Levenberg-Marquardt step of the latent fit (its Gram matrix and gradient), and a step is accepted
    on the float32 cost, so the fit keeps its accuracy (``benchmarks/bench_prior.py``).
    Idempotent: a graph already quantised is left as it is.
    """
    import logging

    import onnx
    from onnxruntime.quantization import QuantType, quantize_dynamic

    path = Path(path)
    graph = onnx.load(str(path)).graph
    if any(n.op_type == "MatMulInteger" for n in graph.node):
        return []  # quantised already (the quantiser also turns the fc layer's Gemm into MatMul + Add)
    nodes = tangent_product_nodes(graph)
    if not nodes:
        return []
    tmp = path.with_suffix(".int8.tmp")
    level = logging.getLogger().level
    logging.getLogger().setLevel(logging.ERROR)  # the quantiser warns that no pre-processing was run
    try:
        quantize_dynamic(str(path), str(tmp), nodes_to_quantize=nodes, weight_type=QuantType.QInt8, per_channel=True)
    finally:
        logging.getLogger().setLevel(level)
    tmp.replace(path)
    return nodes


def _quantize_entry(path: Path, entry: dict) -> None:
    """``quantize_tangent_products`` on a card's Jacobian graph and its ``files`` entry brought up to date."""
    quantize_tangent_products(path)
    entry["sha256"] = sha256_file(path)
    entry["tangent_products"] = "int8"


def quantize_card_jacobian(card_path: str | Path) -> dict:
    """``quantize_tangent_products`` on an exported card's decoder-Jacobian graph (the shipped model's
    graphs fold their weights, so ``reexport_decoder_graphs`` cannot redo them); rewrites the card's
    hash and its rendered ``.md``. Returns the graph's new ``files`` entry. Re-score the card after
    (``rescore_card``): its held-out D(z*) rows come from the graph. A graph that does not match the
    card's hash is refused (ValueError), not re-hashed."""
    card_path = Path(card_path)
    card = json.loads(card_path.read_text())
    entry = card["files"]["decoder_jacobian"]
    path = card_path.parent / entry["file"]
    digest = sha256_file(path)
    if digest != entry["sha256"]:
        raise ValueError(f"{path}: SHA-256 {digest} does not match the card's {entry['sha256']}")
    _quantize_entry(path, entry)
    card_path.write_text(json.dumps(card, indent=1))
    if card_path.with_suffix(".md").is_file():
        write_card_markdown(card, card_path.with_suffix(".md"))
    return entry


def add_gram_output(path: str | Path, latent: int, n_coords: int, frames: int, frame_step: int = 1) -> tuple[list[str], list[str]]:
    """Append the Levenberg-Marquardt normal equations of Eq. (1) to an exported decoder-Jacobian graph (in place).

    New inputs: ``w`` (B, N) 1 for observed coordinates (the rows A keeps), 0 else;
    ``y`` (B, N) the normalised observations; ``c`` (B, 3) the translation (N = ``n_coords``
    = T*J*3, T = ``frames``). New outputs (with J = dD/dz and r = w (D(z) + c - y)):
    ``r`` (B, N); ``cost`` (B,) = ||r||^2; ``gram`` (B, L, L) = (wJ)(wJ)^T;
    ``jtr`` (B, L, 1) = (wJ) r; ``h_zc`` (B, L, 3) = sum over joint-frames of wJ per axis.
    With ``frame_step`` s > 1 the graph's ``jac`` holds the rows of every s-th frame only
    (``model.DecoderJacobian``) and the three sums run over those frames, times s.
    Everything the step needs then runs inside onnxruntime on one thread, instead of
    numpy products that call a multi-threaded BLAS (which stalls on a busy machine).
    """
    import onnx
    from onnx import TensorProto, helper

    model = onnx.load(str(path))
    g = model.graph
    lat, n = int(latent), int(n_coords)
    n_rows = n // frame_step
    dims = next(o for o in g.output if o.name == "jac").type.tensor_type.shape.dim
    dims[1].dim_value, dims[2].dim_value = lat, n_rows  # sizes the exporter left symbolic (reshapes with -1)
    f = TensorProto.FLOAT
    g.input.extend([
        helper.make_tensor_value_info("w", f, ["batch", n]),
        helper.make_tensor_value_info("y", f, ["batch", n]),
        helper.make_tensor_value_info("c", f, ["batch", 3]),
    ])
    g.initializer.extend([
        helper.make_tensor("ne_ax1", TensorProto.INT64, [1], [1]),
        helper.make_tensor("ne_ax2", TensorProto.INT64, [1], [2]),
        helper.make_tensor("ne_shape3", TensorProto.INT64, [3], [0, -1, 3]),
        helper.make_tensor("ne_shape2", TensorProto.INT64, [2], [0, -1]),
        helper.make_tensor("ne_shape4", TensorProto.INT64, [4], [0, lat, -1, 3]),
        helper.make_tensor("ne_frames", TensorProto.INT64, [3], [0, frames, -1]),
        helper.make_tensor("ne_s0", TensorProto.INT64, [1], [0]),  # Slice: start, end, axis, step
        helper.make_tensor("ne_s1", TensorProto.INT64, [1], [frames]),
        helper.make_tensor("ne_s2", TensorProto.INT64, [1], [1]),
        helper.make_tensor("ne_s3", TensorProto.INT64, [1], [frame_step]),
        helper.make_tensor("ne_step", f, [], [float(frame_step)]),
    ])
    nodes = [
        # residual r = w (D(z) + c - y)
        helper.make_node("Reshape", ["x", "ne_shape3"], ["ne_x3"]),
        helper.make_node("Unsqueeze", ["c", "ne_ax1"], ["ne_c3"]),
        helper.make_node("Add", ["ne_x3", "ne_c3"], ["ne_xc3"]),
        helper.make_node("Reshape", ["ne_xc3", "ne_shape2"], ["ne_xc"]),
        helper.make_node("Sub", ["ne_xc", "y"], ["ne_d"]),
        helper.make_node("Mul", ["ne_d", "w"], ["r"]),
        helper.make_node("ReduceSumSquare", ["r"], ["cost"], axes=[1], keepdims=0),
    ]
    w_rows, r_rows = "w", "r"
    if frame_step > 1:  # the frames the Jacobian rows are of
        for name in ("w", "r"):
            nodes += [
                helper.make_node("Reshape", [name, "ne_frames"], [f"ne_{name}_t"]),
                helper.make_node("Slice", [f"ne_{name}_t", "ne_s0", "ne_s1", "ne_s2", "ne_s3"], [f"ne_{name}_ts"]),
                helper.make_node("Reshape", [f"ne_{name}_ts", "ne_shape2"], [f"ne_{name}_rows"]),
            ]
        w_rows, r_rows = "ne_w_rows", "ne_r_rows"
    nodes += [
        # rows of A J and the products (times the frame step: the sums stand for every frame)
        helper.make_node("Unsqueeze", [w_rows, "ne_ax1"], ["ne_w3"]),
        helper.make_node("Mul", ["jac", "ne_w3"], ["ne_jw"]),
        helper.make_node("Transpose", ["ne_jw"], ["ne_jwt"], perm=[0, 2, 1]),
        helper.make_node("MatMul", ["ne_jw", "ne_jwt"], ["ne_gram"]),
        helper.make_node("Unsqueeze", [r_rows, "ne_ax2"], ["ne_r3"]),
        helper.make_node("MatMul", ["ne_jw", "ne_r3"], ["ne_jtr"]),
        helper.make_node("Reshape", ["ne_jw", "ne_shape4"], ["ne_jw4"]),
        helper.make_node("ReduceSum", ["ne_jw4", "ne_ax2"], ["ne_h_zc"], keepdims=0),
    ]
    for name in ("gram", "jtr", "h_zc"):
        nodes.append(helper.make_node("Mul", [f"ne_{name}", "ne_step"], [name]) if frame_step > 1
                     else helper.make_node("Identity", [f"ne_{name}"], [name]))
    g.node.extend(nodes)
    g.output.extend([
        helper.make_tensor_value_info("r", f, ["batch", n]),
        helper.make_tensor_value_info("cost", f, ["batch"]),
        helper.make_tensor_value_info("gram", f, ["batch", lat, lat]),
        helper.make_tensor_value_info("jtr", f, ["batch", lat, 1]),
        helper.make_tensor_value_info("h_zc", f, ["batch", lat, 3]),
    ])
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    init_names = {x.name for x in g.initializer}
    return [i.name for i in g.input if i.name not in init_names], [o.name for o in g.output]


def save_checkpoint(model: TemporalAutoencoder, history: dict, config: TrainConfig, path: str | Path) -> None:
    """Weights, architecture, training config and history in one torch file (``load_checkpoint`` reads it back)."""
    torch.save({"model": model.config, "state_dict": model.state_dict(), "history": history,
                "train_config": config.as_dict()}, str(path))


def load_checkpoint(path: str | Path) -> tuple[TemporalAutoencoder, dict, TrainConfig]:
    """(model, history, config) from ``save_checkpoint``'s file, on the CPU."""
    ckpt = torch.load(str(path), map_location="cpu", weights_only=False)
    model = TemporalAutoencoder(**ckpt["model"])
    model.load_state_dict(ckpt["state_dict"])
    return model.eval(), ckpt["history"], TrainConfig(**ckpt["train_config"])


#: Licence and provenance of each training source (model card; the shipped model uses only these).
SOURCE_LICENCES = {
    "uiprmd_vicon": "UI-PRMD (Vakanski et al., Data 2018), Vicon Plug-in-Gait markers -> joint centres; "
    "PDDL 1.0 (public domain, any use)",
    "uiprmd_kinect_v1": "UI-PRMD Kinect v1 skeletons of the same sessions; PDDL 1.0 (public domain, any use)",
    "bvh": "CMU Graphics Lab mocap (subject 131: free for research and commercial use, not for resale) and "
    "Xia et al. style takes via deep-motion-editing (BSD-2-Clause)",
    "c3d_markers": "CMU Graphics Lab mocap subjects 85 and 135 marker C3D (free for research and commercial use)",
    "kinect_v2": "microsoft/LabanotationSuite Kinect v2 recordings (MIT), tracked joints only",
}


def train_and_export(
    data_dir: str | Path,
    out_dir: str | Path,
    config: TrainConfig,
    held_out: tuple[str, ...] = HELD_OUT,
    log: Callable[[str], None] = print,
    evaluate: bool = True,
    kinect_v1: bool = True,
) -> dict:
    """Load ``data_dir``, train, export the three graphs and write the card ``<out>/canonical.json``."""
    takes = canonical_takes(data_dir, kinect_v1=kinect_v1)
    train_takes, test_takes = split_takes(takes, held_out)
    log(
        f"{len(train_takes)} training takes ({sum(t.duration_s for t in train_takes) / 60:.1f} min), "
        f"{len(test_takes)} held out ({', '.join(sorted({t.group for t in test_takes})) or 'none'})"
    )
    model, history = train(train_takes, test_takes, config, log)
    return export_with_card(model, history, train_takes, test_takes, out_dir, config, log=log, evaluate=evaluate)


def _augmentation_text(config: TrainConfig) -> str:
    text = ("rotation about y in [-pi, pi] (before facing normalisation), left/right mirroring (x negated + joint "
            "swap), speed x0.7..x1.4 by linear resampling, ")
    if config.proportion_sigma > 0:
        text += (f"body proportions (each bone, left and right alike, scaled by exp(N(0, {config.proportion_sigma:g})), "
                 "streamfix.prior.data.rescale_bones), ")
    return text + "joint dropping (subsets, limbs, partial layouts, runs of frames)"


def export_with_card(
    model: TemporalAutoencoder,
    history: dict,
    train_takes: list[Take],
    test_takes: list[Take],
    out_dir: str | Path,
    config: TrainConfig,
    log: Callable[[str], None] = print,
    evaluate: bool = True,
) -> dict:
    """Export a trained ``model`` (``train``'s model and history) to ONNX and write its card ``<out>/canonical.json``
    and ``canonical.md``, with the held-out scores when ``evaluate``. Apart from ``train`` so that a model trained
    on another machine (a GPU box, saved with ``save_checkpoint``) is exported and scored here the same way."""
    out_dir = Path(out_dir)
    files = export_onnx(model, out_dir)
    sources = {}
    for t in train_takes:
        rec = sources.setdefault(t.source, {"takes": 0, "minutes": 0.0, "licence": SOURCE_LICENCES.get(t.source, "?"),
                                            "batch_share": config.shares.get(t.source)})
        rec["takes"] += 1
        rec["minutes"] += t.duration_s / 60
    for rec in sources.values():
        rec["minutes"] = round(rec["minutes"], 2)
    card = {
        "name": "streamfix temporal-convolution autoencoder prior (Lohit et al.), canonical body",
        "skeleton": "canonical",
        "joints": list(CANONICAL_JOINTS),
        "n_joints": len(CANONICAL_JOINTS),
        "window": config.window,
        "rate_hz": MODEL_RATE_HZ,
        "latent": config.latent,
        "channels": config.channels,
        "levels": config.levels,
        "files": files,
        "layouts": {name: {"joints": lay.n_joints, "observes": [CANONICAL_JOINTS[i] for i in np.flatnonzero(lay.covered)]}
                    for name, lay in LAYOUTS.items()},
        "normalisation": {
            "root_joint": "pelvis",
            "root_index": 0,
            "hips": list(CANONICAL_HIPS),
            "method": "layout -> canonical joints (streamfix.canonical), then x_norm = R_y(theta) (x - root_t) / k; "
            "root_t = pelvis (midpoint of the hip centres; interpolated where missing; mean of observed joints if "
            "absent from the window); k = median over observed scale bones of (median bone length / reference "
            "length), clipped to [0.5, 2]; theta = facing angle about y onto facing_template",
            "reference_bone_lengths_m": history["reference_bone_lengths_m"],
            "bones": CANONICAL_BONES.tolist(),
            "scale_bones_child_index": list(CANONICAL_SCALE_BONES),
            "facing_template": history["facing_template"],
            "facing": "turned about y by the 2-D Procrustes angle onto facing_template (mean canonical pose of the "
            "Kinect v2 takes, root-relative, scale-normalised, facing the sensor)",
            "unobserved_input": "0 in y and 0 in mask",
        },
        "training": {
            "sources": sources,
            "minutes": round(sum(t.duration_s for t in train_takes) / 60, 2),
            "takes": len(train_takes),
            "held_out": sorted({t.group for t in test_takes}),
            "split": "whole people (UI-PRMD subject 6) and whole takes held out, never frames of a training take",
            "observed": "BVH retargeted: all joints; Kinect v2 CSV: tracked joints only; CMU marker C3D: joints from "
            "markers (streamfix.io.prior_takes._CMU_MARKERS_TO_KINECT); UI-PRMD Vicon: Plug-in-Gait joint centres "
            "(streamfix.io.prior_takes.plug_in_gait_joints); UI-PRMD Kinect v1: legs unobserved in m01/m05",
            "augmentation": _augmentation_text(config),
            "loss": "masked (ambient) MSE over the data's observed joint-frames (Lohit et al. Sec. 4.2)",
            "config": config.as_dict(),
            "final_train_loss": history["train_loss"][-1],
            "final_held_out_loss": history["held_out_loss"][-1] if history["held_out_loss"] else None,
            "seconds": history.get("seconds"),
            "torch": history.get("torch", torch.__version__),
            "device": config.device,
        },
        "held_out_protocol": HELD_OUT_PROTOCOL,
        "held_out_scores": [],
    }
    card_path = out_dir / "canonical.json"
    card_path.write_text(json.dumps(card, indent=1))
    if evaluate and test_takes:
        _score_card(card, card_path, test_takes, config.seed, log)
    write_card_markdown(card, out_dir / "canonical.md")
    log(f"wrote {card_path} and canonical.md")
    return card


HELD_OUT_PROTOCOL = (
    "streamfix.evaluation.occlusion in canonical joints at 30 Hz: each 64-frame window of "
    "a held-out take loses joints for the whole window (random 25 % / 50 % = test OTP 75 / 50, or a whole "
    "limb of 4 joints); rmse_m over every ground-truth joint-frame (observed ones are returned unchanged), "
    "rmse_dropped_m over the dropped ones; methods nearest_joint (baseline), prior_encode D(E(Y)), "
    "prior_latent D(z*) (one decoder-Jacobian call at E(Y), then streamfix.prior.init.CHORD_STEPS damped "
    "Levenberg-Marquardt step(s) on it: what the streaming bridge runs); both prior methods average each "
    "window's reconstruction with that of its mirror image, mirrored back (streamfix.prior.init.MIRROR_ENSEMBLE)"
)


def _score_card(card: dict, card_path: Path, test_takes: list[Take], seed: int, log: Callable[[str], None]) -> None:
    """The card's held-out scores (``HELD_OUT_PROTOCOL``) with today's inference, written into ``card_path``."""
    from streamfix.evaluation.occlusion import score_prior_on_takes

    card["held_out_protocol"] = HELD_OUT_PROTOCOL
    card["held_out_scores"] = score_prior_on_takes(card_path, test_takes, seed=seed)
    card_path.write_text(json.dumps(card, indent=1))
    for rec in card["held_out_scores"]:
        log(f"held-out {rec['take']:>16s} {rec['pattern']:>10s} OTP {rec['test_otp']:3.0f}%  {rec['method']:>12s}  "
            f"RMSE {100 * rec['rmse_m']:.2f} cm (dropped {100 * rec['rmse_dropped_m']:.2f})")


def rescore_card(card_path: str | Path, data_dir: str | Path, log: Callable[[str], None] = print) -> dict:
    """Score an exported model's held-out takes again with today's inference (the model is unchanged: the
    graphs' hashes are checked on load) and rewrite its card and ``.md``; the held-out takes are the
    card's own (``training.held_out``), the seed its training seed."""
    card_path = Path(card_path)
    card = json.loads(card_path.read_text())
    held = tuple(card["training"]["held_out"])
    kinect_v1 = "uiprmd_kinect_v1" in card["training"]["sources"]
    _, test_takes = split_takes(canonical_takes(data_dir, kinect_v1=kinect_v1), held)
    if not test_takes:
        raise ValueError(f"{card_path}: none of the card's held-out takes ({', '.join(held)}) is in {data_dir}")
    _score_card(card, card_path, test_takes, int(card["training"]["config"]["seed"]), log)
    write_card_markdown(card, card_path.with_suffix(".md"))
    log(f"wrote {card_path} and {card_path.with_suffix('.md').name}")
    return card


def write_card_markdown(card: dict, path: str | Path) -> None:
    """The human-readable model card beside the JSON one (data, licences, normalisation, held-out scores, hashes)."""
    tr = card["training"]
    lines = [
        f"# {card['name']}",
        "",
        f"Generated by `streamfix train-prior` from `{Path(path).stem}.json` (the machine-readable card, which "
        "`streamfix.prior.runtime.Prior.load` checks); do not edit by hand.",
        "",
        f"Joints: {card['n_joints']} canonical ({', '.join(card['joints'])}); window {card['window']} frames at "
        f"{card['rate_hz']:g} Hz; latent {card['latent']}; {card['channels']} channels x {card['levels']} levels.",
        "",
        "## Training data (whole people/takes held out: " + ", ".join(tr["held_out"]) + ")",
        "",
        "| source | takes | minutes | batch share | licence |",
        "| --- | ---: | ---: | ---: | --- |",
    ]
    for name, src in tr["sources"].items():
        lines.append(f"| {name} | {src['takes']} | {src['minutes']:.1f} | {src['batch_share']} | {src['licence']} |")
    lines += [f"| **total** | {tr['takes']} | {tr['minutes']:.1f} | | |", "",
              f"Observed joints: {tr['observed']}.", "", f"Augmentation: {tr['augmentation']}.", "",
              f"Loss: {tr['loss']}. Config: `{json.dumps(tr['config'])}`; {tr.get('seconds')} s of training "
              f"(torch {tr.get('torch', '?')}).", "",
              "## Layouts", "", "| layout | joints | canonical joints observed |", "| --- | ---: | --- |"]
    for name, lay in card["layouts"].items():
        lines.append(f"| {name} | {lay['joints']} | {len(lay['observes'])}: {', '.join(lay['observes'])} |")
    norm = card["normalisation"]
    lines += ["", "## Normalisation", "", norm["method"] + ".", "", norm["facing"] + ".", "",
              "## Held-out scores (RMSE over all joint-frames, cm; dropped joints only in brackets)", "",
              card["held_out_protocol"] + ".", "",
              "| take | pattern | OTP % | windows | nearest joint | D(E(Y)) | D(z*) |", "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    cells: dict = {}
    for r in card["held_out_scores"]:
        cells.setdefault((r["take"], r["pattern"], r["test_otp"]), {})[r["method"]] = r
    for (take, pattern, otp), c in cells.items():
        f = lambda m: f"{100 * c[m]['rmse_m']:.2f} ({100 * c[m]['rmse_dropped_m']:.1f})" if m in c else "-"  # noqa: E731
        win = next(iter(c.values()))["windows"]
        lines.append(f"| {take} | {pattern} | {otp:g} | {win} | {f('nearest_joint')} | {f('prior_encode')} | {f('prior_latent')} |")
    lines += ["", "## Files", "", "| role | file | SHA-256 |", "| --- | --- | --- |"]
    for role, entry in card["files"].items():
        lines.append(f"| {role} | {entry['file']} | `{entry['sha256']}` |")
    if card["files"].get("decoder_jacobian", {}).get("tangent_products") == "int8":
        lines += ["", "The decoder-Jacobian graph runs the products of its forward-mode tangents in 8-bit integers "
                  "(`streamfix.prior.train.quantize_tangent_products`): D(z) and the cost are float32, dD/dz within "
                  "a few per cent; the held-out D(z*) rows above are measured with it."]
    Path(path).write_text("\n".join(lines) + "\n")
