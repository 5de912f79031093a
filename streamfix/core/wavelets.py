"""Orthogonal temporal wavelet operator W for the smoothness term of Yang et al. (2019).

Yang et al., Eq. (6): ``E_smooth(A) = ||W A||_1`` with ``W`` a J-level (J = 2)
orthogonal Daubechies wavelet basis applied along *time* to each coordinate
channel (each column of the paper's ``3T x S`` matrix splits into three
coordinate channels; here an array ``(T, C)`` has one time series per column).
The A-subproblem (Eq. 13 -> 14) relies on ``W^T W = I``; this module makes that
hold *exactly* for any number of frames ``T``:

* Let ``q = 2**level`` and ``r = T mod q``. The last ``T - r`` frames are
  transformed by PyWavelets' ``'periodization'`` DWT, which for lengths divisible
  by ``2**level`` is an orthogonal (square) matrix, also when the filter is longer
  than the signal.
* The first ``r`` frames (0..3 for two levels) are passed through unchanged as
  extra *approximation* coefficients. The operator is block diagonal
  ``diag(I_r, W_per)``, hence square and orthogonal: ``W^T W = W W^T = I``.
  The leftover frames sit at the *start* because in streaming the newest frames are
  at the end of a window and deserve the full temporal prior.

Coefficient layout (rows of ``W @ X``):
``[pass-through r | cA_level | cD_level | ... | cD_1]``. The approximation part is
the first ``r + (T - r) / 2**level`` rows; :func:`detail_mask` marks the rest.
Penalising only detail coefficients keeps the l1 term from pulling the coarse
trajectory (and so the body) toward the origin.
"""
from __future__ import annotations

import warnings
from functools import lru_cache

import numpy as np
import pywt
from scipy.sparse import csr_matrix

__all__ = ["TemporalWavelet", "wavelet_matrix", "detail_mask"]

# How W is applied (all give the same orthogonal operator): up to _DENSE_MAX_T frames
# as a cached dense matrix (one BLAS call), up to _SPARSE_MAX_T as a cached CSR matrix
# (~40 non-zeros per row for db10, level 2), beyond that through pywt (O(T) memory).
_DENSE_MAX_T = 256
_SPARSE_MAX_T = 1024


def _split(n_frames: int, level: int) -> tuple[int, int]:
    """(pass-through frames r, periodised length T - r)."""
    q = 2**level
    r = n_frames % q
    return r, n_frames - r


def _check_level(n_frames: int, level: int) -> None:
    if level < 1:
        raise ValueError(f"wavelet level must be >= 1, got {level}")
    if n_frames < 2**level:
        raise ValueError(
            f"a {level}-level wavelet needs at least {2**level} frames, got {n_frames}"
        )


def _forward_pywt(x: np.ndarray, wavelet: str, level: int) -> np.ndarray:
    r, _ = _split(x.shape[0], level)
    with warnings.catch_warnings():
        # pywt warns when the filter outlasts the signal; periodization stays orthogonal
        warnings.simplefilter("ignore", UserWarning)
        coeffs = pywt.wavedec(x[r:], wavelet, mode="periodization", level=level, axis=0)
    return np.concatenate([x[:r]] + coeffs, axis=0)


def _inverse_pywt(c: np.ndarray, wavelet: str, level: int) -> np.ndarray:
    n_frames = c.shape[0]
    r, n = _split(n_frames, level)
    sizes = [n >> level] + [n >> k for k in range(level, 0, -1)]
    bounds = np.cumsum([r] + sizes)
    parts = [c[bounds[i]:bounds[i + 1]] for i in range(len(sizes))]
    rec = pywt.waverec(parts, wavelet, mode="periodization", axis=0)
    return np.concatenate([c[:r], rec], axis=0)


@lru_cache(maxsize=64)
def _dense(n_frames: int, wavelet: str, level: int) -> np.ndarray:
    w = _forward_pywt(np.eye(n_frames), wavelet, level)
    w.setflags(write=False)
    return w


@lru_cache(maxsize=16)
def _sparse(n_frames: int, wavelet: str, level: int) -> tuple[csr_matrix, csr_matrix]:
    w = _forward_pywt(np.eye(n_frames), wavelet, level)
    w[np.abs(w) < 1e-15] = 0.0  # round-off of exact zeros outside the filter support
    return csr_matrix(w), csr_matrix(w.T)


def wavelet_matrix(n_frames: int, wavelet: str = "db10", level: int = 2) -> np.ndarray:
    """The ``(T, T)`` orthogonal matrix W (read-only, cached). Rows = coefficients."""
    _check_level(n_frames, level)
    return _dense(int(n_frames), str(wavelet), int(level))


def detail_mask(n_frames: int, level: int = 2) -> np.ndarray:
    """``(T,)`` bool: True for rows of ``W @ X`` that are detail coefficients."""
    _check_level(n_frames, level)
    r, n = _split(n_frames, level)
    mask = np.ones(n_frames, dtype=bool)
    mask[: r + (n >> level)] = False
    return mask


class TemporalWavelet:
    """W and W^T along axis 0 of ``(T, C)`` arrays (vectorised over channels C).

    ``forward(X) = W X`` gives ``(T, C)`` coefficients; ``inverse(C) = W^T C``.
    Since W is square and orthogonal, ``inverse(forward(X)) == X`` to round-off.
    """

    def __init__(self, n_frames: int, wavelet: str = "db10", level: int = 2) -> None:
        _check_level(n_frames, level)
        pywt.Wavelet(wavelet)  # ValueError naming the wavelet if unknown
        if pywt.Wavelet(wavelet).orthogonal is False:
            raise ValueError(f"wavelet {wavelet!r} is not orthogonal; W^T W = I needs one (e.g. 'db10')")
        self.n_frames = int(n_frames)
        self.wavelet = str(wavelet)
        self.level = int(level)
        self.detail = detail_mask(self.n_frames, self.level)
        self._w = wavelet_matrix(self.n_frames, self.wavelet, self.level) if self.n_frames <= _DENSE_MAX_T else None
        self._ws = _sparse(self.n_frames, self.wavelet, self.level) if self._w is None and self.n_frames <= _SPARSE_MAX_T else None

    def _check(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape[0] != self.n_frames:
            raise ValueError(f"expected {self.n_frames} frames along axis 0, got {x.shape[0]}")
        return x

    def forward(self, x: np.ndarray) -> np.ndarray:
        """W X for ``x`` of shape ``(T, ...)``."""
        x = self._check(x)
        if self._w is not None:
            return (self._w @ x.reshape(self.n_frames, -1)).reshape(x.shape)
        if self._ws is not None:
            return (self._ws[0] @ x.reshape(self.n_frames, -1)).reshape(x.shape)
        return _forward_pywt(x, self.wavelet, self.level)

    def inverse(self, c: np.ndarray) -> np.ndarray:
        """W^T C for coefficients ``c`` of shape ``(T, ...)``."""
        c = self._check(c)
        if self._w is not None:
            return (self._w.T @ c.reshape(self.n_frames, -1)).reshape(c.shape)
        if self._ws is not None:
            return (self._ws[1] @ c.reshape(self.n_frames, -1)).reshape(c.shape)
        return _inverse_pywt(c, self.wavelet, self.level)
