"""How far joints must move, at the least, for every bone to keep one length.

Why: a cleaner that makes a sensor's bones rigid has to move joints, and the real-Kinect
bars of issue 8 ask for both steady bones and tracked joints that barely move. This says
what rigid bones cost whatever the method: a bone whose length is off by ``e`` in a frame
needs its two ends moved by ``|d_i| + |d_j| >= e`` together (the triangle inequality), so
the least summed movement of the joints that count is at least the optimum of the linear
program

    minimise  sum_j c_j a_j   subject to   a_i + a_j >= e_b  for every bone b = (i, j),  a >= 0

per frame, ``c_j`` 1 for a joint whose movement is counted (tracked) and 0 for one that may
move freely (inferred or missing). Every output whose bones all have the target lengths
moves the counted joints at least that much; the bound is what the geometry demands
before any smoothing. Pure arrays in, numbers out (``scipy.optimize.linprog``, HiGHS).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import csr_matrix

from .isometry import bone_lengths_per_frame
from .points import finite_points
from .robust_stats import nanmedian

__all__ = ["least_shift_to_rigid", "CHUNK_FRAMES"]

CHUNK_FRAMES = 1000
"""Frames solved as one program (each frame's is independent; a chunk keeps HiGHS's memory bounded)."""


def least_shift_to_rigid(
    positions: np.ndarray,
    observed: np.ndarray,
    counted: np.ndarray,
    bones: np.ndarray,
    lengths: np.ndarray | None = None,
    keep: float = 0.0,
) -> np.ndarray:
    """``(T,)`` metres: per frame, the least summed movement of the ``counted`` joints that
    puts every bone at its target length (the module's linear program; a lower bound).

    ``positions`` ``(T, J, 3)`` m; ``observed`` ``(T, J)``: a bone is constrained in a frame
    where both ends are observed; ``counted`` ``(T, J)``: joints whose movement is summed
    (the others move for free); ``bones`` ``(B, 2)``; ``lengths`` ``(B,)`` m, the targets
    (None: each bone's median over its observed frames, the constant length nearest the
    sensor's in the mean); ``keep``: the fraction of each bone's length error that may
    remain (0: rigid; 0.1: every bone's deviation from its length cut to a tenth, one way
    to a bone-length CV a tenth of the input's).
    """
    if not 0.0 <= keep < 1.0:
        raise ValueError(f"keep must be in [0, 1), got {keep}")
    x = np.asarray(positions, dtype=np.float64)
    obs = np.asarray(observed, dtype=bool) & finite_points(x)
    cost = np.asarray(counted, dtype=bool) & obs
    b = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    T, J = obs.shape
    if T == 0 or len(b) == 0:
        return np.zeros(T)
    length = np.where(obs[:, b[:, 0]] & obs[:, b[:, 1]], bone_lengths_per_frame(x, b), np.nan)
    if lengths is None:
        lengths = nanmedian(length, axis=0)  # NaN for a bone never seen: unconstrained
    need = (1.0 - float(keep)) * np.abs(length - np.asarray(lengths, dtype=np.float64)[None, :])
    out = np.zeros(T)
    # frames are independent programs: solved CHUNK_FRAMES at a time, so a long recording
    # costs time in proportion and bounded memory
    for s in range(0, T, CHUNK_FRAMES):
        e = min(T, s + CHUNK_FRAMES)
        out[s:e] = _solve_frames(need[s:e], cost[s:e], b)
    return out


def _solve_frames(need: np.ndarray, cost: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """The module's program for frames ``need`` ``(n, B)`` m (NaN: bone unconstrained) and
    ``cost`` ``(n, J)`` bool, as one block-diagonal program; ``(n,)`` optima."""
    n, J = cost.shape
    t, k = np.nonzero(np.isfinite(need) & (need > 0))
    if len(t) == 0:
        return np.zeros(n)
    rows = np.repeat(np.arange(len(t)), 2)
    cols = np.stack([t * J + bones[k, 0], t * J + bones[k, 1]], axis=1).ravel()
    a_ub = csr_matrix((np.full(len(cols), -1.0), (rows, cols)), shape=(len(t), n * J))
    res = linprog(cost.ravel().astype(np.float64), A_ub=a_ub, b_ub=-need[t, k], bounds=(0, None), method="highs")
    if res.status != 0:
        raise RuntimeError(f"least_shift_to_rigid: the linear program did not solve ({res.message})")
    return (res.x.reshape(n, J) * cost).sum(axis=1)
