"""Run the exported prior with onnxruntime only (no torch): encode, decode, D(E(Y)).

A model is a JSON *card* beside three ONNX graphs (see ``streamfix/prior/models/``):

* ``encoder``: inputs ``y`` (B, T, J, 3) normalised coordinates (0 where unobserved) and
  ``mask`` (B, T, J) 0/1; output ``z`` (B, L);
* ``decoder``: input ``z`` (B, L); output ``x`` (B, T, J, 3) normalised coordinates;
* ``decoder_jacobian``: inputs ``z`` (B, L), ``w`` (B, N) 0/1, ``y`` (B, N), ``c`` (B, 3)
  (N = T*J*3); outputs ``x``, ``jac`` (B, L, N / s) the dD/dz rows of every s-th frame
  (s = the card's ``files.decoder_jacobian.frame_step``, 1 when absent; exact, or within a few
  per cent where ``files.decoder_jacobian.tangent_products`` is ``"int8"``: the tangent
  products in 8-bit integers, ``train.quantize_tangent_products``), and the
  Levenberg-Marquardt normal-equation terms ``r``, ``cost``, ``gram``, ``jtr``, ``h_zc``
  used by the latent-space fit (``streamfix.prior.latent``; see ``train.add_gram_output``).

The card carries the window length T (frames), the rate (Hz), the latent size L,
the normalisation (``streamfix.prior.normalize``: root joint and reference bone
lengths) and a SHA-256 of each graph, checked on load.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np

from .normalize import NormSpec, WindowNorm, _clean, denormalise

__all__ = ["Prior", "DEFAULT_CARD", "sha256_file", "load_default_prior", "set_default_prior"]

DEFAULT_CARD = Path(__file__).resolve().parent / "models" / "canonical.json"


def sha256_file(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _read_only(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only: the card's arrays are computed once per model and shared by every caller."""
    a.setflags(write=False)
    return a


def _session(path: Path, threads: int):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


@dataclass
class Prior:
    """A loaded prior: card (dict) and onnxruntime sessions."""

    card: dict
    directory: Path
    card_name: str
    _encoder: object
    _decoder: object
    _jacobian: object

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(cls, path: str | Path | None = None, *, threads: int = 1, verify: bool = True) -> "Prior":
        """Load a card (``.json`` file, or a directory holding one ``*.json``); default: the shipped canonical model.

        ``threads``: onnxruntime intra-op threads (1 = single-threaded, the default, so
        that many bodies can be solved on separate cores). ``verify`` checks each
        graph's SHA-256 against the card.
        """
        card_path = DEFAULT_CARD if path is None else Path(path)
        if card_path.is_dir():
            cards = sorted(card_path.glob("*.json"))
            if len(cards) != 1:
                raise FileNotFoundError(f"{card_path}: expected exactly one model card *.json, found {len(cards)}")
            card_path = cards[0]
        if not card_path.is_file():
            raise FileNotFoundError(
                f"prior model card not found at {card_path}; train one with `streamfix train-prior --out DIR`"
            )
        card = json.loads(card_path.read_text())
        directory = card_path.parent
        sessions = []
        for role in ("encoder", "decoder", "decoder_jacobian"):
            entry = card["files"][role]
            f = directory / entry["file"]
            if verify:
                digest = sha256_file(f)
                if digest != entry["sha256"]:
                    raise ValueError(f"{f}: SHA-256 {digest} does not match the card's {entry['sha256']}")
            sessions.append(_session(f, threads))
        return cls(card, directory, card_path.name, *sessions)

    # --------------------------------------------------------------- properties
    @property
    def window(self) -> int:
        """Frames per window T."""
        return int(self.card["window"])

    @property
    def rate_hz(self) -> float:
        return float(self.card["rate_hz"])

    @property
    def n_joints(self) -> int:
        return int(self.card["n_joints"])

    @property
    def latent_size(self) -> int:
        return int(self.card["latent"])

    @cached_property
    def bones(self) -> np.ndarray:
        return _read_only(np.asarray(self.card["normalisation"]["bones"], dtype=np.intp).reshape(-1, 2))

    @cached_property
    def reference_lengths(self) -> np.ndarray:
        return _read_only(np.asarray(self.card["normalisation"]["reference_bone_lengths_m"], dtype=np.float64))

    @cached_property
    def facing_template(self) -> np.ndarray | None:
        t = self.card["normalisation"].get("facing_template")
        return None if t is None else _read_only(np.asarray(t, dtype=np.float64))

    @cached_property
    def mirror(self) -> np.ndarray | None:
        """``(J,)`` each joint's left/right twin (``streamfix.canonical.CANONICAL_MIRROR``) for a model of
        the canonical joints, which ``train-prior`` trains with mirrored copies; None for other joint sets."""
        from streamfix.canonical import CANONICAL_JOINTS, CANONICAL_MIRROR

        return CANONICAL_MIRROR if tuple(self.card.get("joints", ())) == CANONICAL_JOINTS else None

    @property
    def jacobian_frame_step(self) -> int:
        """The decoder-Jacobian graph's ``jac`` holds the rows of every this-many-th frame (1: every frame)."""
        return int(self.card["files"]["decoder_jacobian"].get("frame_step", 1))

    @property
    def jacobian_per_window(self) -> bool:
        """True when the Jacobian graph runs its tangent products in 8-bit integers (the card's
        ``tangent_products`` "int8"): their scale is set per call, so each window gets a call of its own
        and its fit never depends on which other windows share its batch."""
        return self.card["files"]["decoder_jacobian"].get("tangent_products") == "int8"

    @property
    def root_index(self) -> int:
        return int(self.card["normalisation"]["root_index"])

    @property
    def norm_kwargs(self) -> dict:
        """``normalise`` keyword arguments of this model (root, fallback hips, scale bones) from the card."""
        norm = self.card["normalisation"]
        kw = {"root": int(norm["root_index"])}
        if "hips" in norm:
            kw["hips"] = tuple(int(i) for i in norm["hips"])
        if "scale_bones_child_index" in norm:
            kw["scale_bones"] = tuple(int(i) for i in norm["scale_bones_child_index"])
        return kw

    @cached_property
    def norm_spec(self) -> NormSpec:
        """This model's ``normalise`` constants, resolved once (the latency path normalises every window)."""
        return NormSpec.of(self.bones, self.reference_lengths, template=self.facing_template, **self.norm_kwargs)

    # ------------------------------------------------------------ raw networks
    def encode(self, y: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """E(Y): normalised windows (B, T, J, 3) and masks (B, T, J) -> latents (B, L)."""
        y = np.asarray(y, dtype=np.float32)
        mask = np.asarray(mask, dtype=np.float32)
        self._check(y.shape[1:3], "encode")
        y = np.where(mask[..., None] > 0, y, 0.0).astype(np.float32)
        return self._encoder.run(None, {"y": y, "mask": mask})[0]

    def decode(self, z: np.ndarray) -> np.ndarray:
        """D(z): latents (B, L) -> normalised windows (B, T, J, 3) (float32)."""
        return self._decoder.run(None, {"z": np.asarray(z, dtype=np.float32).reshape(-1, self.latent_size)})[0]

    def decode_with_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(z) (B, T, J, 3) and the dD/dz rows (B, L, T'*J*3) of every ``jacobian_frame_step``-th frame
        (T' = T / step; int8-rounded tangents in a card whose graph says so), float32: one onnxruntime call
        for the batch, or one per window (``jacobian_per_window``)."""
        z = np.asarray(z, dtype=np.float32).reshape(-1, self.latent_size)
        b, n = z.shape[0], self.window * self.n_joints * 3
        feeds = {"z": z, "w": np.zeros((b, n), np.float32), "y": np.zeros((b, n), np.float32),
                 "c": np.zeros((b, 3), np.float32)}
        x, jac = self._run_jacobian(["x", "jac"], feeds)
        return x, jac

    def normal_equations(
        self, z: np.ndarray, w: np.ndarray, y: np.ndarray, c: np.ndarray, with_jacobian: bool = False
    ) -> dict[str, np.ndarray]:
        """One Levenberg-Marquardt linearisation of Eq. (1) at (z, c), in one onnxruntime call.

        ``w`` (B, N) 0/1 observed coordinates, ``y`` (B, N) normalised observations,
        ``c`` (B, 3) translation (N = T*J*3). Returns float32 arrays ``x`` D(z) (B, T, J, 3),
        ``r`` = w (D(z) + c - y) (B, N), ``cost`` ||r||^2 (B,), ``gram`` (wJ)(wJ)^T (B, L, L),
        ``jtr`` (wJ) r (B, L, 1) and ``h_zc`` (B, L, 3) (J = dD/dz); with ``with_jacobian`` also
        ``jac`` J (B, L, N).
        """
        feeds = {
            "z": np.asarray(z, dtype=np.float32).reshape(-1, self.latent_size),
            "w": np.asarray(w, dtype=np.float32),
            "y": np.asarray(y, dtype=np.float32),
            "c": np.asarray(c, dtype=np.float32),
        }
        names = ["x", "r", "cost", "gram", "jtr", "h_zc"] + (["jac"] if with_jacobian else [])
        return dict(zip(names, self._run_jacobian(names, feeds)))

    def _run_jacobian(self, names: list[str], feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        """The Jacobian graph's ``names`` outputs for a batch: one call, or one per window (``jacobian_per_window``)."""
        b = len(feeds["z"])
        if b == 1 or not self.jacobian_per_window:
            return self._jacobian.run(names, feeds)
        parts = [self._jacobian.run(names, {k: v[i:i + 1] for k, v in feeds.items()}) for i in range(b)]
        return [np.concatenate(p) for p in zip(*parts)]

    def as_batch(self, window: np.ndarray, observed: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray, bool]:
        """Validate a (T, J, 3) window + (T, J) mask, or batches of them, for this model.

        Returns ``(windows (B, T, J, 3), masks (B, T, J), single)``; ``single`` is True
        when one window was given (callers return ``out[0]`` then).
        """
        window = np.asarray(window, dtype=np.float64)
        observed = np.asarray(observed, dtype=bool)
        single = window.ndim == 3
        if single:
            window, observed = window[None], observed[None]
        if window.shape[:3] != observed.shape or window.shape[-1] != 3:
            raise ValueError(f"expected (B, T, J, 3) windows and (B, T, J) masks, got {window.shape} and {observed.shape}")
        self._check(window.shape[1:3], what)
        return window, observed, single

    def _check(self, tj: tuple, what: str) -> None:
        if tuple(tj) != (self.window, self.n_joints):
            raise ValueError(
                f"prior.{what}: expected windows of {self.window} frames x {self.n_joints} joints, "
                f"got {tj[0]} x {tj[1]} (use streamfix.prior.init.prior_initial_guess for other lengths)"
            )

    # ----------------------------------------------------------- metre windows
    def normalise(self, windows: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[WindowNorm]]:
        """Metre windows (B, T, J, 3) + masks (B, T, J) -> normalised (B, T, J, 3), masks, per-window norms."""
        clean, obs = _clean(windows, observed)
        spec = self.norm_spec
        out = [spec.normalise(w, o) for w, o in zip(clean, obs)]  # windows, not frames
        return np.stack([y for y, _ in out]), obs, [n for _, n in out]

    def reconstruct(self, window: np.ndarray, observed: np.ndarray) -> np.ndarray:
        """D(E(Y)) in metres: (T, J, 3) window + (T, J) mask, or batches (B, T, J, 3) + (B, T, J).

        Every joint of the output comes from the decoder (observed ones too); see
        ``streamfix.prior.init.prior_initial_guess`` to keep observed joints.
        """
        window, observed, single = self.as_batch(window, observed, "reconstruct")
        y, obs, norms = self.normalise(window, observed)
        x = self.decode(self.encode(y, obs))
        out = np.stack([denormalise(xi, n) for xi, n in zip(x, norms)])
        return out[0] if single else out


_DEFAULT_PATH: str | None = None


def set_default_prior(path: str | Path | None) -> None:
    """Make ``path`` (a card or a directory holding one) the process-wide default prior; None = the shipped one.

    What ``streamfix serve/clean --prior PATH`` call: everything that takes ``prior=None``
    (the streaming bridge, ``prior_initial_guess``, ``fill_long_gaps``, ``limb_residuals``)
    then uses it. The card is loaded and checked at once, so a bad path fails here and the
    default stays what it was.
    """
    global _DEFAULT_PATH
    previous = _DEFAULT_PATH
    _DEFAULT_PATH = None if path is None else str(path)
    _load_cached.cache_clear()
    try:
        load_default_prior()
    except Exception:
        _DEFAULT_PATH = previous
        _load_cached.cache_clear()
        raise


@lru_cache(maxsize=4)
def _load_cached(path: str | None, threads: int) -> Prior:
    return Prior.load(path, threads=threads)


def load_default_prior(path: str | None = None, threads: int = 1) -> Prior:
    """The given prior, else the one ``set_default_prior`` chose, else the shipped one; loaded once per process."""
    return _load_cached(path if path is not None else _DEFAULT_PATH, threads)
