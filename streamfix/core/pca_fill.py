"""PCA filling of a whole take and of a streamed body's windows (Li et al. 2020).

:func:`pca_fill` fills partial gaps by Eq. (4)/(8) (:func:`streamfix.core.pca_gapfill.fill_gaps`),
then whole missing frames by Eq. (16) (:func:`streamfix.core.pca_blackouts.fill_blackouts`),
then linearly what neither could. :class:`PcaGapFiller` keeps a training set (reference
takes plus the body's recent clean history) for the streaming engine's windows.
Positions ``(T, J, 3)`` metres, NaN = missing; filled values never replace observed ones.
"""
from __future__ import annotations

import numpy as np

from .interpolate import interpolate_linear
from .pca_blackouts import fill_blackouts
from .pca_gapfill import fill_gaps
from .pca_training import DEFAULT_ENERGY, TrainingSet, _as_training, _observed_mask

__all__ = ["PcaGapFiller", "pca_fill"]


def _interp_leftover(x: np.ndarray, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation per joint coordinate (edges hold); fallback for what PCA left.

    Joints with no sample at all keep ``x``. Returns ``(positions, filled mask)``.
    """
    est, filled = interpolate_linear(x, obs)
    out = x.copy()
    out[filled] = est[filled]
    return out, filled


def pca_fill(
    positions: np.ndarray,
    observed: np.ndarray | None,
    training,
    *,
    energy: float = DEFAULT_ENERGY,
    min_observed_joints: int = 3,
    blackout_window: int = 200,
    fallback_linear: bool = True,
    bases: dict | None = None,
    corotating: bool = False,
    **gap_kwargs,
) -> tuple[np.ndarray, np.ndarray]:
    """Everything: partial gaps by Eq. (4)/(8), whole missing frames by Eq. (16).

    Frames with fewer than ``min_observed_joints`` observed joints count as blackout
    frames. ``bases`` (a dict kept by the caller) caches Eq. (16)'s temporal bases
    between calls with the same training set. Whatever neither estimator could fill (e.g. no training frame has the
    joint) is linearly interpolated when ``fallback_linear``. ``corotating``: blackouts are
    blended with the spline in co-rotating frames (marker sets; see
    :func:`~streamfix.core.pca_blackouts.fill_blackouts`). Returns
    ``(filled, filled_mask)``; with nothing missing the output equals the input.
    """
    x = np.asarray(positions, dtype=np.float64)
    obs = _observed_mask(x, observed)
    out = x.copy()
    out[~obs] = np.nan
    if obs.all():
        return out, np.zeros_like(obs)
    ts = _as_training(training, x.shape[1])
    out1, f1 = fill_gaps(out, obs, ts, energy=energy, min_observed_joints=min_observed_joints, **gap_kwargs)
    have = obs | f1
    black = obs.sum(axis=1) < min_observed_joints
    out2, f2 = fill_blackouts(out1, have, ts, blackout=black, window=blackout_window, bases=bases,
                              corotating=corotating)
    have2 = have | f2
    if fallback_linear and not have2.all():
        out2, f3 = _interp_leftover(out2, have2)
        have2 = have2 | f3
    filled = have2 & ~obs
    out2[obs] = x[obs]
    return out2, filled


class PcaGapFiller:
    """Fill long gaps and blackouts in windows of one body's stream.

    Usage (streaming engine)::

        filler = PcaGapFiller()                    # or PcaGapFiller(training=reference_takes)
        filler.fit(clean_history)                  # (T_hist, J, 3) m, the body's recent clean output
        filled, filled_mask = filler.fill(window_positions, window_observed)

    ``fit`` may be called again at any time (e.g. every few seconds) with newer
    history; reference takes given to the constructor are kept and combined with
    the history. ``ready`` is False until some training exists; ``fill`` then only
    interpolates linearly (``filled_mask`` still marks what was produced).
    """

    def __init__(self, training=None, *, energy: float = DEFAULT_ENERGY, blackout_window: int = 200,
                 min_observed_joints: int = 3, piece_frames: int = 240, max_history: int = 3000) -> None:
        self.energy = energy
        self.blackout_window = blackout_window
        self.min_observed_joints = min_observed_joints
        self.piece_frames = piece_frames
        self.max_history = max_history
        self._reference: list[np.ndarray] = []
        if training is not None:
            ts = training if isinstance(training, TrainingSet) else TrainingSet(
                [training] if isinstance(training, np.ndarray) else list(training))
            self._reference = list(ts.motions)
        self._history: np.ndarray | None = None
        self._training: TrainingSet | None = TrainingSet(self._reference) if self._reference else None
        self._bases: dict = {}

    @property
    def ready(self) -> bool:
        return self._training is not None

    def fit(self, history: np.ndarray) -> "PcaGapFiller":
        """(Re)train from the body's recent clean history ``(T_hist, J, 3)`` metres.

        Only the last ``max_history`` frames are kept; NaN samples are allowed (frames
        lacking a joint are simply not used for templates that need it).
        """
        h = np.asarray(history, dtype=np.float64)
        if h.ndim != 3 or h.shape[2] != 3:
            raise ValueError(f"history must be (T_hist, J, 3) metres, got {h.shape}")
        if self._reference and h.shape[1] != self._reference[0].shape[1]:
            raise ValueError(f"history has {h.shape[1]} joints, reference takes have {self._reference[0].shape[1]}")
        self._history = h[-self.max_history:].copy()
        self._training = TrainingSet(self._reference + [self._history])
        self._bases = {}
        return self

    def fill(self, positions: np.ndarray, observed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Fill a window ``(T, J, 3)``; returns ``(filled, filled_mask (T, J))``."""
        x = np.asarray(positions, dtype=np.float64)
        obs = _observed_mask(x, observed)
        if self._training is None:
            out = x.copy()
            out[~obs] = np.nan
            out, f = _interp_leftover(out, obs)
            return out, f
        return pca_fill(x, obs, self._training, energy=self.energy, min_observed_joints=self.min_observed_joints,
                        blackout_window=min(self.blackout_window, x.shape[0]), piece_frames=self.piece_frames,
                        bases=self._bases)
