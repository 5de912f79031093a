"""Joint positions to local bone rotations against a rest pose, and forward kinematics back.

Animation formats (BVH) and avatar protocols (VMC) carry a hierarchy of joints, each
with a fixed *rest offset* from its parent and a *local rotation* per frame; sensors and
the cleaner give positions. :func:`solve_local_rotations` turns positions into local
rotations; :func:`forward_kinematics` turns them back.

Model (per node ``j`` with parent ``p``; frames are vectorised)::

    G_j = G_p @ L_j                  global rotation from the local one (root: G = L)
    x_j = x_p + G_p @ o_j            position from the parent's rotation and the rest offset o_j

so in the rest pose (every ``L = I``) node ``j`` sits at ``x_p + o_j``: the rest pose is
whatever the offsets describe (a BVH file's OFFSETs, or a T-pose built from bone
lengths; the caller chooses, see :mod:`streamfix.humanoid`).

The solve, parents before children, for node ``j``:

* its *aim targets* are the descendants reached through zero-length offsets only (a BVH
  ``LHipJoint`` at the hips aims at ``LeftUpLeg`` below it): rest vector ``r_k`` (the sum
  of offsets from ``j`` to ``k``, zero-length links contributing nothing) and current
  vector ``d_k = x_k - x_j``;
* **swing**: the shortest rotation taking the parent-carried rest direction
  ``G_p r_a`` of the primary target ``a`` onto ``d_a`` (so ``a`` is reproduced exactly
  when the bone length matches the rest offset);
* **twist** about ``d_a``: the angle that best aligns the other targets (hips twist from
  the two hip joints, a chest from the shoulders), in closed form from the components
  perpendicular to ``d_a``. With one target the twist is the parent's (no information);
  so it is with targets whose rest vectors lie (nearly) along the primary's, within
  :data:`TWIST_MIN_ANGLE_DEG`: a T-pose's thumb along the hand has no perpendicular part
  at rest, and the angle from it would be noise (a wrist spun by up to 180 degrees from
  one frame to the next);
* a node without targets (a leaf, or only zero-length leaves) keeps its parent's
  rotation (``L = I``); so does any frame where a needed position is NaN.

Positions are reproduced exactly (to round-off) when every node has at most one
target with non-zero offset or its targets move rigidly together, and bone lengths equal
the offsets' norms; otherwise the non-primary targets carry the deformation.
:func:`local_positions` gives the per-frame offsets ``G_p^T (x_j - x_p)`` that make
:func:`forward_kinematics` exact in every case (VMC sends them).

Quaternions are ``(x, y, z, w)`` (scipy's order and VMC's), right-handed.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from .points import finite_points, point_dots, point_norms

__all__ = [
    "parent_array",
    "topological_order",
    "depth_levels",
    "subtree_mask",
    "aim_targets",
    "solve_local_rotations",
    "solve_rotation_matrices",
    "forward_kinematics",
    "global_rotations",
    "local_positions",
    "quaternions_to_matrices",
    "matrices_to_quaternions",
]

_ZERO_LENGTH = 1e-9  # offsets shorter than this (same units as the offsets) carry no direction


def parent_array(bones: np.ndarray, n_joints: int) -> np.ndarray:
    """``(J,)`` parent index of each joint (-1 for the root) from ``(B, 2)`` (parent, child) bones.

    ValueError unless the bones form one tree (one root, one parent per joint, no cycle).
    """
    bones = np.asarray(bones, dtype=np.intp).reshape(-1, 2)
    parents = np.full(n_joints, -1, dtype=np.intp)
    for p, c in bones:
        if parents[c] >= 0:
            raise ValueError(f"joint {c} has two parents ({parents[c]} and {p}): the bones are not a tree")
        parents[c] = p
    roots = np.flatnonzero(parents < 0)
    if len(roots) != 1:
        raise ValueError(f"the bones are not one tree: {len(roots)} joints have no parent")
    topological_order(parents)  # raises on a cycle
    return parents


def topological_order(parents: np.ndarray) -> np.ndarray:
    """Node indices ordered parents before children (Kinect v2 lists Neck before its parent)."""
    parents = np.asarray(parents, dtype=np.intp)
    depth = np.zeros(len(parents), dtype=np.intp)
    for j in range(len(parents)):
        k, steps = parents[j], 0
        while k >= 0:
            k, steps = parents[k], steps + 1
            if steps > len(parents):
                raise ValueError(f"the parent links from node {j} form a cycle")
        depth[j] = steps
    return np.argsort(depth, kind="stable")


def subtree_mask(parents: np.ndarray, root: int) -> np.ndarray:
    """``(J,)`` bool: ``root`` and the nodes hanging below it."""
    parents = np.asarray(parents, dtype=np.intp)
    inside = np.zeros(len(parents), bool)
    inside[root] = True
    for j in topological_order(parents):
        if parents[j] >= 0 and inside[parents[j]]:
            inside[j] = True
    return inside


def aim_targets(parents: np.ndarray, offsets: np.ndarray) -> list[list[tuple[int, np.ndarray]]]:
    """Per node, its aim targets ``[(k, rest vector from the node to k), ...]`` (see module doc).

    The first target is the primary; callers order children so that the one to be
    reproduced exactly comes first (:func:`solve_local_rotations` takes ``primary``).
    """
    n = len(parents)
    children: list[list[int]] = [[] for _ in range(n)]
    for c in range(n):
        if parents[c] >= 0:
            children[parents[c]].append(c)
    zero = np.linalg.norm(offsets, axis=1) < _ZERO_LENGTH
    targets: list[list[tuple[int, np.ndarray]]] = [[] for _ in range(n)]
    for j in range(n):
        stack = [(c, offsets[c]) for c in reversed(children[j])]
        while stack:
            k, r = stack.pop()
            if zero[k]:
                stack.extend((c, r + offsets[c]) for c in reversed(children[k]))
            else:
                targets[j].append((k, r))
    return targets


TWIST_MIN_ANGLE_DEG = 10.0
"""A non-primary target whose rest vector is within this angle (degrees) of the primary's does not twist."""
_TWIST_MIN_SIN = float(np.sin(np.radians(TWIST_MIN_ANGLE_DEG)))


def _twists(rest: np.ndarray, primary_rest: np.ndarray) -> bool:
    """Whether a target at ``rest`` can tell the twist about the primary bone (not along it)."""
    a, b = np.linalg.norm(rest), np.linalg.norm(primary_rest)
    return bool(a > 0 and b > 0 and np.linalg.norm(np.cross(rest, primary_rest)) > _TWIST_MIN_SIN * a * b)


@lru_cache(maxsize=64)
def depth_levels(parents_bytes: bytes) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(nodes, their parents), ...]`` by tree depth, root first; ``n`` stands for "no parent".
    ``parents_bytes``: a ``(J,)`` intp parent array's ``tobytes()`` (the key it is cached by)."""
    parents = np.frombuffer(parents_bytes, dtype=np.intp)
    n = len(parents)
    depth = np.zeros(n, dtype=np.intp)
    for j in topological_order(parents):
        depth[j] = 0 if parents[j] < 0 else depth[parents[j]] + 1
    return [(nodes, np.where(parents[nodes] < 0, n, parents[nodes]))
            for nodes in (np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1 if n else 0))]


@lru_cache(maxsize=64)
def _plan(parents_bytes: bytes, offsets_bytes: bytes, n: int, primary: tuple) -> list[dict]:
    """The solve, level by level (nodes of equal depth together), computed once per hierarchy.

    Per level: ``nodes``; ``parent`` (``n`` stands for "no parent": the identity);
    ``aimed`` (positions in ``nodes`` of the nodes with targets), their primary target
    ``aim`` and its rest vector ``aim_rest``; the other targets ``sec``, ``sec_rest``
    and ``sec_owner`` (position in ``aimed``) with ``sec_sum`` ``(k, m)`` adding them up
    per owner.
    """
    parents = np.frombuffer(parents_bytes, dtype=np.intp)
    offsets = np.frombuffer(offsets_bytes, dtype=np.float64).reshape(n, 3)
    first = dict(primary)
    targets = aim_targets(parents, offsets)
    levels = []
    for nodes, parent in depth_levels(parents_bytes):
        aimed, aim, aim_rest, sec, sec_rest, sec_owner = [], [], [], [], [], []
        for i, j in enumerate(nodes):
            tj = sorted(targets[j], key=lambda t: t[0] != first[j]) if j in first else targets[j]
            if not tj:
                continue
            aimed.append(i)
            aim.append(tj[0][0])
            aim_rest.append(tj[0][1])
            for k, rk in tj[1:]:
                if not _twists(rk, tj[0][1]):
                    continue
                sec.append(k)
                sec_rest.append(rk)
                sec_owner.append(len(aimed) - 1)
        sec_sum = np.zeros((len(sec), len(aimed)))
        sec_sum[np.arange(len(sec)), sec_owner] = 1.0
        levels.append({
            "nodes": nodes, "parent": parent,
            "aimed": np.array(aimed, dtype=np.intp), "aim": np.array(aim, dtype=np.intp),
            "aim_rest": np.array(aim_rest).reshape(-1, 3), "sec": np.array(sec, dtype=np.intp),
            "sec_rest": np.array(sec_rest).reshape(-1, 3), "sec_owner": np.array(sec_owner, dtype=np.intp),
            "sec_sum": sec_sum, "twisted": sec_sum.any(axis=0),
        })
    return levels


def _unit(v: np.ndarray) -> np.ndarray:
    n = point_norms(v)[..., None]
    return v / np.where(n > 0, n, 1.0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (np.cross costs more than the maths on small arrays)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _skew(v: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` cross-product matrices ``[v]x`` of ``(..., 3)`` vectors."""
    K = np.zeros(v.shape + (3,))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def _swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` shortest rotations taking unit vectors ``a`` onto ``b`` (both ``(..., 3)``)."""
    K = _skew(_cross(a, b))
    c = point_dots(a, b)
    opposite = c < -1.0 + 1e-9
    R = np.eye(3) + K + (K @ K) / np.where(opposite, 1.0, 1.0 + c)[..., None, None]
    if opposite.any():  # half turn about any axis perpendicular to a
        aa = a[opposite]
        helper = np.where(np.abs(aa[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        u = _unit(_cross(aa, helper))
        R[opposite] = 2.0 * u[:, :, None] * u[:, None, :] - np.eye(3)
    return R


def _axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotations by ``angle`` (rad) about unit ``axis`` ``(..., 3)`` (Rodrigues)."""
    K = _skew(axis)
    return np.eye(3) + np.sin(angle)[..., None, None] * K + (1.0 - np.cos(angle))[..., None, None] * (K @ K)


def solve_local_rotations(
    positions: np.ndarray,
    parents: np.ndarray,
    offsets: np.ndarray,
    primary: dict[int, int] | None = None,
) -> np.ndarray:
    """Local rotations ``(T, N, 4)`` (x y z w) of every node for positions ``(T, N, 3)``.

    ``parents`` ``(N,)`` (-1 for the root); ``offsets`` ``(N, 3)`` the
    rest offsets in the parent's frame (same length unit as ``positions``). ``primary``
    maps a node to the target node whose direction it reproduces exactly (default: its
    first target in node order). The root's translation is ``positions[:, root]``.
    Vectorised over frames and over the nodes of each tree level.
    """
    return matrices_to_quaternions(solve_rotation_matrices(positions, parents, offsets, primary)[0])


def solve_rotation_matrices(
    positions: np.ndarray,
    parents: np.ndarray,
    offsets: np.ndarray,
    primary: dict[int, int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Local and global rotation matrices ``(T, N, 3, 3)`` each; see :func:`solve_local_rotations`."""
    X = np.asarray(positions, dtype=np.float64)
    parents = np.asarray(parents, dtype=np.intp)
    offsets = np.asarray(offsets, dtype=np.float64)
    T, N = X.shape[:2]
    if parents.shape != (N,) or offsets.shape != (N, 3):
        raise ValueError(f"positions have {N} nodes; parents {parents.shape} and offsets {offsets.shape} must match")
    key = tuple(sorted((int(a), int(b)) for a, b in (primary or {}).items()))
    G = np.empty((T, N + 1, 3, 3))  # global rotations; slot N is the identity (the root's "parent")
    G[:, N] = np.eye(3)
    L = np.empty((T, N, 3, 3))
    for lev in _plan(parents.tobytes(), offsets.tobytes(), N, key):
        nodes, w = lev["nodes"], lev["aimed"]
        Gp = G[:, lev["parent"]]
        Gl = Gp.copy()  # nodes without targets keep their parent's rotation
        if len(w):
            Gpw = Gp[:, w]
            owner = nodes[w]
            rest = _unit(np.einsum("tmij,mj->tmi", Gpw, lev["aim_rest"]))
            d = X[:, lev["aim"]] - X[:, owner]
            ok = finite_points(d) & (point_dots(d, d) > 0)
            da = np.where(ok[..., None], _unit(np.nan_to_num(d)), rest)
            G0 = _swing(rest, da) @ Gpw
            if len(lev["sec"]):  # twist about the primary bone that best aligns the other targets
                so = lev["sec_owner"]
                p = np.einsum("tkij,kj->tki", G0[:, so], lev["sec_rest"])
                q = np.nan_to_num(X[:, lev["sec"]] - X[:, owner[so]])
                axis = da[:, so]
                p_perp = p - point_dots(p, axis)[..., None] * axis
                q_perp = q - point_dots(q, axis)[..., None] * axis
                sin = point_dots(axis, _cross(p_perp, q_perp)) @ lev["sec_sum"]
                cos = point_dots(p_perp, q_perp) @ lev["sec_sum"]
                angle = np.where(ok & lev["twisted"], np.arctan2(sin, cos), 0.0)
                G0 = _axis_angle(da, angle) @ G0
            Gl[:, w] = G0
        G[:, nodes] = Gl
        L[:, nodes] = np.swapaxes(Gp, -1, -2) @ Gl  # Gp^T G
    return L, G[:, :N]


def global_rotations(local_quaternions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """``(T, N, 3, 3)`` global rotation matrices from local quaternions ``(T, N, 4)``."""
    L = quaternions_to_matrices(local_quaternions)
    T, N = L.shape[:2]
    G = np.empty((T, N + 1, 3, 3))
    G[:, N] = np.eye(3)
    for nodes, parent in depth_levels(np.asarray(parents, dtype=np.intp).tobytes()):
        G[:, nodes] = G[:, parent] @ L[:, nodes]
    return G[:, :N]


def forward_kinematics(
    root_positions: np.ndarray,
    local_quaternions: np.ndarray,
    parents: np.ndarray,
    offsets: np.ndarray,
    local_offsets: np.ndarray | None = None,
) -> np.ndarray:
    """Node positions ``(T, N, 3)`` from the root's ``(T, 3)`` and local rotations ``(T, N, 4)``.

    ``offsets`` ``(N, 3)`` are the rest offsets; ``local_offsets`` ``(T, N, 3)``, when
    given, replace them frame by frame (as :func:`local_positions` returns them).
    """
    parents = np.asarray(parents, dtype=np.intp)
    G = global_rotations(local_quaternions, parents)
    T, N = G.shape[:2]
    off = np.broadcast_to(np.asarray(offsets, dtype=np.float64), (T, N, 3)) if local_offsets is None else local_offsets
    X = np.zeros((T, N + 1, 3))  # slot N: the root's "parent", at the origin with the identity
    G = np.concatenate([G, np.broadcast_to(np.eye(3), (T, 1, 3, 3))], axis=1)
    for nodes, parent in depth_levels(parents.tobytes()):
        if (parent == N).any():
            X[:, nodes[parent == N]] = np.asarray(root_positions, dtype=np.float64)[:, None]
        child = parent < N
        if child.any():
            n, p = nodes[child], parent[child]
            X[:, n] = X[:, p] + np.einsum("tnij,tnj->tni", G[:, p], off[:, n])
    return X[:, :N]


def local_positions(positions: np.ndarray, local_quaternions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """``(T, N, 3)`` each node's position in its parent's frame, ``G_p^T (x_j - x_p)``; the root's own position."""
    parents = np.asarray(parents, dtype=np.intp)
    G = global_rotations(local_quaternions, parents)
    out = np.array(positions, dtype=np.float64, copy=True)
    has_parent = parents >= 0
    rel = positions[:, has_parent] - positions[:, parents[has_parent]]
    out[:, has_parent] = np.einsum("tnji,tnj->tni", G[:, parents[has_parent]], rel)
    return out


def quaternions_to_matrices(q: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotation matrices of unit quaternions ``(..., 4)`` (x y z w)."""
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrices_to_quaternions(R: np.ndarray) -> np.ndarray:
    """``(..., 4)`` unit quaternions (x y z w, w >= 0) of rotation matrices ``(..., 3, 3)``."""
    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(R.shape[:-2] + (4,))
    return np.where(q[..., 3:] < 0, -q, q)
