"""Whole-frame blackouts splined in co-rotating frames: each marker's trajectory is
interpolated in the frame of its most rigid neighbours, not in the room.

Not in the papers. A cubic spline through each marker's room coordinates cuts the corner
of a turning segment (a marker 10 cm from the segment's centre, turning through 90 degrees
in a gap, is splined inside its arc): rigid distances shrink and every marker of the
segment is misplaced. Here marker ``i`` and its ``n_neighbours`` most rigid partners
(:func:`~streamfix.core.rigid_pairs.rigid_neighbours`) form a cluster; on every present
frame the cluster's centroid ``c_t`` and rotation ``R_t`` (Kabsch, onto the cluster's
shape at the present frame nearest the gap) are measured; in the gap the centroid and the
rotation's unit quaternion (signs made continuous, renormalised) are splined, and the
marker's non-rigid remainder (skin, a wand) is splined in the cluster's frame. Present
frames are reproduced exactly; a cluster that does not turn gives the room spline.

Why a cluster per marker rather than segments: no segment table is needed for an unknown
marker set; how many partners a cluster takes is :func:`neighbour_count`'s.
Pure functions: arrays in, arrays out; positions in metres, rows are frames.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .interpolate import spline_operator
from .pca_normalise import kabsch
from .rigid_pairs import pair_distance_spread, rigid_neighbours

__all__ = ["corotating_spline", "corotating_blackouts", "neighbour_count", "DEFAULT_NEIGHBOURS"]

DEFAULT_NEIGHBOURS = 8
"""The most partners per marker's cluster (:func:`neighbour_count`)."""


def neighbour_count(n_markers: int) -> int:
    """Partners per marker's cluster: a fifth of the markers, 2 to :data:`DEFAULT_NEIGHBOURS`.

    Few partners follow one segment but measure its turn from a few, partly non-rigid
    markers; many straddle segments that turn differently (with every marker, the whole body
    is one rotation), and how many a segment holds grows with the marker set. Measured on
    ``eval --protocol blackout``'s CMU takes (41 markers: 4 to 10 partners all beat the room
    spline, 8 the most) and on random subsets of their markers: with 12 or 16 markers, 8
    partners lost to the room spline and 2-4 beat it; with 20-28, 4-8 beat it."""
    return int(np.clip(int(n_markers) // 5, 2, DEFAULT_NEIGHBOURS))


CHUNK_ELEMENTS = 2_000_000
"""Numbers per cluster array of a chunk of a stack's windows (one window of 140 present
frames, 41 markers and 9 per cluster: 0.15 M), so a stack of hundreds stays small."""


def corotating_spline(window: np.ndarray, missing_rows: np.ndarray, neighbours: np.ndarray | None = None,
                      *, n_neighbours: int | None = None, spline: np.ndarray | None = None) -> np.ndarray:
    """The missing rows of ``window`` ``(m, J, 3)``, or of each of a stack ``(K, m, J, 3)``
    (every marker finite on the other rows, at least 4 of them), splined in co-rotating
    frames (module doc).

    ``neighbours`` ``(J, k)``: each marker's rigid partners (None: the ``n_neighbours``,
    default :func:`neighbour_count`, most rigid over the present rows, of the first window
    of a stack). ``spline``: the
    :func:`~streamfix.core.interpolate.spline_operator` of these present / missing rows when
    the caller has it. Returns ``(n_missing, J, 3)`` (``(K, n_missing, J, 3)``); with fewer
    than 2 partners per marker (no rotation to measure), the room spline.
    """
    x = np.asarray(window, dtype=np.float64)
    single = x.ndim == 3
    x = x[None] if single else x
    miss = np.asarray(missing_rows, dtype=bool)
    rows = np.arange(len(miss))
    S = spline_operator(rows[~miss], rows[miss]) if spline is None else np.asarray(spline, dtype=np.float64)
    P = x[:, ~miss]                                           # (K, p, J, 3) present frames
    K, p, J, _ = P.shape
    if neighbours is None:
        k = neighbour_count(J) if n_neighbours is None else n_neighbours
        neighbours = rigid_neighbours(pair_distance_spread(P[0]), k)
    nb = np.asarray(neighbours, dtype=np.intp).reshape(J, -1)
    if nb.shape[1] < 2 or not miss.any():
        out = np.einsum("qp,kpjc->kqjc", S, P)
        return out[0] if single else out
    near = int(np.argmin(np.abs(rows[~miss] - np.flatnonzero(miss)[0])))
    cluster = np.concatenate([np.arange(J)[:, None], nb], axis=1)     # (J, k+1)
    chunk = max(1, CHUNK_ELEMENTS // (p * J * cluster.shape[1] * 3))
    out = np.concatenate([_corotating(P[i:i + chunk], cluster, near, S) for i in range(0, K, chunk)])
    return out[0] if single else out


def corotating_blackouts(temporal: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """``temporal`` ``(T, J, 3)`` m (each joint's spline through ``observed``, complete
    elsewhere) with its whole-frame blackouts splined in co-rotating frames instead
    (:func:`corotating_spline`): for marker sets, where a spline
    through room coordinates cuts a turning segment's corner. Markers never seen keep theirs."""
    empty = ~np.asarray(observed, dtype=bool).any(axis=1)
    seen = np.isfinite(temporal[~empty]).all(axis=(0, 2))
    if not empty.any() or int((~empty).sum()) < 4 or int(seen.sum()) < 3:
        return temporal
    out = temporal.copy()
    rows = out[empty]
    rows[:, seen] = corotating_spline(temporal[:, seen], empty)
    out[empty] = rows
    return out


def _corotating(P: np.ndarray, cluster: np.ndarray, near: int, S: np.ndarray) -> np.ndarray:
    """:func:`corotating_spline` for present frames ``P`` ``(K, p, J, 3)``, clusters
    ``(J, k+1)`` (the marker first), reference row ``near`` and spline operator ``S``."""
    K, p, J, _ = P.shape
    n = cluster.shape[1]
    n_miss = S.shape[0]
    X = P[:, :, cluster]                                      # (K, p, J, k+1, 3)
    c = X.mean(axis=3)                                        # (K, p, J, 3) cluster centroids
    local = X - c[:, :, :, None, :]
    ref = local[:, near]                                      # (K, J, k+1, 3) reference shapes
    R = kabsch(local.reshape(-1, n, 3),
               np.broadcast_to(ref[:, None], local.shape).reshape(-1, n, 3)).reshape(K, p, J, 3, 3)
    # local_t @ R_t ~ ref: the marker's remainder in its cluster's frame
    remainder = (local[:, :, :, 0, None, :] @ R)[..., 0, :] - ref[:, None, :, 0]
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(K, p, J, 4)
    flip = np.sign(np.einsum("kpjc,kpjc->kpj", q[:, 1:], q[:, :-1]))  # q and -q: one rotation, no jumps
    flip[flip == 0] = 1.0
    q[:, 1:] *= np.cumprod(flip, axis=1)[..., None]
    q_gap = (S @ q.reshape(K, p, -1)).reshape(K, n_miss, J, 4)
    q_gap /= np.linalg.norm(q_gap, axis=3, keepdims=True)
    R_gap = Rotation.from_quat(q_gap.reshape(-1, 4)).as_matrix().reshape(K, n_miss, J, 3, 3)
    c_gap = (S @ c.reshape(K, p, -1)).reshape(K, n_miss, J, 3)
    rem_gap = (S @ remainder.reshape(K, p, -1)).reshape(K, n_miss, J, 3)
    return c_gap + (R_gap @ (ref[:, None, :, 0] + rem_gap)[..., None])[..., 0]
