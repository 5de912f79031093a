"""BVH motion files: hierarchy parsing and vectorised forward kinematics.

:func:`read_bvh` returns global joint positions in metres as a
:class:`~streamfix.motion.Motion` whose skeleton is built from the file's hierarchy.

Forward kinematics (per joint j with parent p, all frames at once)::

    t_j   = OFFSET_j + (Xposition, Yposition, Zposition)_j        (zero if no position channels)
    R_j   = R_c1 @ R_c2 @ R_c3      rotation channels composed in the order CHANNELS lists them
    G_j   = G_p @ R_j                global orientation
    x_j   = x_p + G_p @ t_j          global position (root: G_p = I, x_p = 0)

so position and rotation channels may appear in any order; rotations are in degrees
(``Zrotation Yrotation Xrotation`` means R = Rz Ry Rx, the usual BVH convention).

Units: BVH has no unit field. ``scale`` multiplies every length; when it is None the
rule below picks it from the rest-pose height H (vertical extent of the OFFSET
skeleton including End Sites, in file units):

=====================  ===============  =================================
H in file units        scale            what it is
=====================  ===============  =================================
0.5 <= H < 4           1.0              metres
10 <= H < 50           0.056444         CMU "units" (CMU, Xia et al.; the data README)
50 <= H < 90           0.0254           inches
90 <= H < 400          0.01             centimetres
400 <= H < 4000        0.001            millimetres
=====================  ===============  =================================

Anything else raises and asks for an explicit ``scale``. CMU subject 131 and the Xia
takes have H of about 30 (1.7 m), so they get 0.056444.

Skeleton: one joint per ROOT/JOINT in file order (parents first); bones are the
parent->child pairs. End Sites are left out unless ``include_end_sites=True`` (then
they are joints named ``<parent>_End``). The skeleton is named
``bvh:<J>j-<hash>`` from its joint names and bones (identical hierarchies share a
name, e.g. both CMU 131 takes) and registered. ``meta["bone_lengths"]`` holds the
OFFSET norms times scale for each bone: the file's exact bone lengths, in metres.

The frame rate is 1 / Frame Time, snapped to the nearest integer when within 0.1 %
(``.0083333`` -> 120 Hz).

Writing (:func:`write_bvh`): joint positions become rotation channels through
:func:`streamfix.core.bone_rotations.solve_local_rotations` (swing onto the bone, twist
from sibling bones). A motion read from a BVH file (``meta["bvh_hierarchy"]``, kept
through cleaning) is written with that file's hierarchy unchanged: names, OFFSETs,
CHANNELS order, End Sites and units. Position channels carry the root's (and any other
translating joint's) measured translation; rotation channels are the local rotation as
Euler angles in the listed order (a joint with fewer than three rotation channels gets
the closest angles it can hold). Joint positions are reproduced to round-off where bone
lengths equal the OFFSETs and siblings move rigidly together (CMU/Xia hierarchies branch
through zero-length joints, so every bone is aimed exactly). Any other tree skeleton
gets a new hierarchy in metres: :func:`streamfix.humanoid.build_rig` (T-pose from the
median bone lengths, zero-length branch joints named ``<parent>_<child>`` where a joint
has several children), every joint with ``Xposition Yposition Zposition Zrotation
Yrotation Xrotation``: the rotations carry the motion against the T-pose and the
position channels the difference between the measured bone and its OFFSET (a sensor's
bone lengths vary from frame to frame, so this is what keeps the file equal to the
cleaned positions; a tool that applies the root's translation only still gets the
rotations). End Sites sit a quarter of the last bone on. Leaf joints keep their parent's orientation (nothing measures their twist). A
frame whose root position is missing holds the last known one.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..motion import Motion
from ..skeletons import Skeleton, register_skeleton
from .errors import MotionFileError

__all__ = ["read_bvh", "write_bvh", "check_bvh_skeleton", "BvhJoint", "parse_bvh_hierarchy", "bvh_forward_kinematics", "CMU_SCALE", "choose_bvh_scale", "axis_rotations"]

CMU_SCALE = 0.056444  # CMU mocap units -> metres (data README)
_POSITION_CHANNELS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
_ROTATION_CHANNELS = {"Xrotation": 0, "Yrotation": 1, "Zrotation": 2}
_SCALE_RULE = (  # (low, high, scale, label)
    (0.5, 4.0, 1.0, "metres"),
    (10.0, 50.0, CMU_SCALE, "CMU units"),
    (50.0, 90.0, 0.0254, "inches"),
    (90.0, 400.0, 0.01, "centimetres"),
    (400.0, 4000.0, 0.001, "millimetres"),
)


@dataclass
class BvhJoint:
    """One node of the hierarchy (a ROOT/JOINT, or an End Site)."""

    name: str
    parent: int  # index into the node list, -1 for the root
    offset: np.ndarray  # (3,) file units
    channels: list[str] = field(default_factory=list)
    channel_start: int = 0  # column of its first channel in a MOTION row
    end_site: bool = False
    line: int = 0


def _tokens(path, lines: list[str]):
    for lineno, line in enumerate(lines, start=1):
        for tok in line.replace("{", " { ").replace("}", " } ").split():
            yield tok, lineno


def parse_bvh_hierarchy(path: str | Path, lines: list[str]) -> tuple[list[BvhJoint], int]:
    """Parse the HIERARCHY section. Returns the nodes and the index of the MOTION line."""
    toks = list(_tokens(path, lines))
    pos = 0

    def take(expect: str | None = None) -> tuple[str, int]:
        nonlocal pos
        if pos >= len(toks):
            last = toks[-1][1] if toks else 1
            raise MotionFileError(
                path, f"unexpected end of file in HIERARCHY" + (f" (expected {expect!r})" if expect else ""), line=last
            )
        tok, ln = toks[pos]
        pos += 1
        if expect is not None and tok != expect:
            shown = tok if len(tok) <= 40 else f"{tok[:40]}... ({len(tok)} characters)"
            raise MotionFileError(path, f"expected {expect!r}, got {shown!r}", line=ln)
        return tok, ln

    def number(what: str) -> float:
        tok, ln = take()
        try:
            return float(tok)
        except ValueError:
            raise MotionFileError(path, f"{what} is not a number: {tok!r}", line=ln) from None

    nodes: list[BvhJoint] = []
    n_channels = 0

    def parse_node(name: str, parent: int, ln: int, end_site: bool) -> None:
        nonlocal n_channels
        take("{")
        tok, oln = take("OFFSET")
        offset = np.array([number(f"OFFSET {'xyz'[k]} of {name!r}") for k in range(3)])
        node = BvhJoint(name, parent, offset, end_site=end_site, line=ln)
        idx = len(nodes)
        nodes.append(node)
        if not end_site:
            tok, cln = take("CHANNELS")
            ctok, _ = take()
            try:
                count = int(ctok)
            except ValueError:
                raise MotionFileError(path, f"CHANNELS count of {name!r} is not an integer: {ctok!r}", line=cln) from None
            if not 0 <= count <= 6:
                raise MotionFileError(path, f"CHANNELS count of {name!r} must be 0..6, got {count}", line=cln)
            chans = []
            for _ in range(count):
                ch, chl = take()
                if ch not in _POSITION_CHANNELS and ch not in _ROTATION_CHANNELS:
                    raise MotionFileError(
                        path,
                        f"bad CHANNELS for {name!r}: {ch!r} is not one of Xposition Yposition Zposition "
                        f"Xrotation Yrotation Zrotation (CHANNELS {count} lists fewer names?)",
                        line=chl,
                    )
                if ch in chans:
                    raise MotionFileError(path, f"bad CHANNELS for {name!r}: {ch} listed twice", line=chl)
                chans.append(ch)
            node.channels = chans
            node.channel_start = n_channels
            n_channels += count
        while True:
            tok, tln = take()
            if tok == "}":
                return
            if end_site:
                raise MotionFileError(path, f"expected '}}' closing End Site of {nodes[parent].name!r}, got {tok!r}", line=tln)
            if tok == "JOINT":
                cname, cln = take()
                parse_node(cname, idx, cln, False)
            elif tok == "End":
                take("Site")
                parse_node(f"{name}_End", idx, tln, True)
            else:
                raise MotionFileError(path, f"expected JOINT, End Site or '}}' inside {name!r}, got {tok!r}", line=tln)

    take("HIERARCHY")
    take("ROOT")
    rname, rln = take()
    parse_node(rname, -1, rln, False)
    tok, ln = take()
    if tok == "ROOT":
        raise MotionFileError(path, "more than one ROOT is not supported", line=ln)
    if tok != "MOTION":
        raise MotionFileError(path, f"expected 'MOTION' after the hierarchy, got {tok!r}", line=ln)
    names = [n.name for n in nodes if not n.end_site]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise MotionFileError(path, f"joint name {dup!r} appears twice in the hierarchy")
    return nodes, ln - 1  # 0-based index of the MOTION line


def axis_rotations(axis: int, deg: np.ndarray) -> np.ndarray:
    """(..., 3, 3) right-handed rotation matrices about axis 0/1/2 (x/y/z) by ``deg`` degrees."""
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(deg.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def bvh_forward_kinematics(nodes: list[BvhJoint], values: np.ndarray) -> np.ndarray:
    """Global positions ``(T, N, 3)`` (file units) of every node, for MOTION ``values (T, C)``.

    Loops over the nodes (hierarchy order), vectorised over frames.
    """
    T = values.shape[0]
    N = len(nodes)
    G = np.empty((N, T, 3, 3))
    X = np.empty((N, T, 3))
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))
    for k, node in enumerate(nodes):
        t = np.broadcast_to(node.offset, (T, 3)).copy()
        R = None
        for c, ch in enumerate(node.channels):
            col = values[:, node.channel_start + c]
            if ch in _POSITION_CHANNELS:
                t[:, _POSITION_CHANNELS[ch]] += col
            else:
                Ra = axis_rotations(_ROTATION_CHANNELS[ch], col)
                R = Ra if R is None else R @ Ra
        if node.parent < 0:
            G[k] = eye if R is None else R
            X[k] = t
        else:
            Gp = G[node.parent]
            G[k] = Gp if R is None else Gp @ R
            X[k] = X[node.parent] + np.einsum("tij,tj->ti", Gp, t)
    return X.transpose(1, 0, 2)


def _rest_positions(nodes: list[BvhJoint]) -> np.ndarray:
    X = np.zeros((len(nodes), 3))
    for k, n in enumerate(nodes):
        X[k] = n.offset + (X[n.parent] if n.parent >= 0 else 0.0)
    return X


def choose_bvh_scale(nodes: list[BvhJoint]) -> tuple[float, str]:
    """The documented unit rule: scale from the rest-pose height (see module doc)."""
    rest = _rest_positions(nodes)
    height = float(rest[:, 1].max() - rest[:, 1].min())
    for low, high, scale, label in _SCALE_RULE:
        if low <= height < high:
            return scale, f"rest-pose height {height:.3g} file units -> {label} (x{scale})"
    raise ValueError(f"cannot tell the units of a skeleton {height:.3g} file units tall; pass scale=")


def _skeleton_from_nodes(nodes: list[BvhJoint], keep: list[int]) -> Skeleton:
    remap = {old: new for new, old in enumerate(keep)}
    names = tuple(nodes[k].name for k in keep)
    bones = tuple((remap[nodes[k].parent], remap[k]) for k in keep if nodes[k].parent >= 0)
    digest = hashlib.sha1(repr((names, bones)).encode()).hexdigest()[:8]
    return Skeleton(f"bvh:{len(names)}j-{digest}", names, bones)


def read_bvh(path: str | Path, scale: float | None = None, *, include_end_sites: bool = False) -> Motion:
    """Read a BVH file: global joint positions in metres (see module doc for units/FK)."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError as exc:
        raise MotionFileError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    nodes, motion_idx = parse_bvh_hierarchy(path, lines)
    n_channels = sum(len(n.channels) for n in nodes)

    # --- MOTION header: "Frames: N" and "Frame Time: dt"
    k = motion_idx + 1
    header: dict[str, tuple[str, int]] = {}
    while k < len(lines) and len(header) < 2:
        s = lines[k].strip()
        k += 1
        if not s:
            continue
        if s.startswith("Frames:"):
            header["frames"] = (s[len("Frames:"):].strip(), k)
        elif s.startswith("Frame Time:"):
            header["dt"] = (s[len("Frame Time:"):].strip(), k)
        else:
            raise MotionFileError(path, f"expected 'Frames:' and 'Frame Time:' after MOTION, got {s[:40]!r}", line=k)
    if "frames" not in header or "dt" not in header:
        missing = "Frames:" if "frames" not in header else "Frame Time:"
        raise MotionFileError(path, f"truncated MOTION block: no {missing!r} line", line=k)
    try:
        n_frames = int(header["frames"][0])
    except ValueError:
        raise MotionFileError(path, f"Frames is not an integer: {header['frames'][0]!r}", line=header["frames"][1]) from None
    try:
        dt = float(header["dt"][0])
    except ValueError:
        raise MotionFileError(path, f"Frame Time is not a number: {header['dt'][0]!r}", line=header["dt"][1]) from None
    if not (np.isfinite(dt) and dt > 0):
        raise MotionFileError(path, f"Frame Time must be positive seconds, got {dt}", line=header["dt"][1])
    if n_frames <= 0:  # as the other readers: nothing to clean, said here rather than by the writer
        raise MotionFileError(path, f"no frames ('Frames: {n_frames}')", line=header["frames"][1])

    rows: list[list[str]] = []
    row_lines: list[int] = []
    for i in range(k, len(lines)):
        parts = lines[i].split()
        if not parts:
            continue
        if len(rows) == n_frames:
            raise MotionFileError(path, f"more frame lines than 'Frames: {n_frames}' declares", line=i + 1)
        if len(parts) != n_channels:
            raise MotionFileError(
                path, f"frame {len(rows)}: expected {n_channels} channel values (the hierarchy's CHANNELS), got {len(parts)}",
                line=i + 1,
            )
        rows.append(parts)
        row_lines.append(i + 1)
    if len(rows) < n_frames:
        raise MotionFileError(
            path, f"truncated MOTION block: 'Frames: {n_frames}' declared, {len(rows)} frame lines found", line=len(lines)
        )
    try:
        values = np.array(rows, dtype=np.float64).reshape(n_frames, n_channels)
    except ValueError:
        for r, ln in zip(rows, row_lines):
            for c, s in enumerate(r):
                try:
                    float(s)
                except ValueError:
                    raise MotionFileError(path, f"channel value {c} is not a number: {s!r}", line=ln) from None
        raise
    if not np.isfinite(values).all():
        r, c = np.argwhere(~np.isfinite(values))[0]
        raise MotionFileError(path, f"channel value {c} is not finite: {rows[r][c]!r}", line=row_lines[r])

    if scale is None:
        try:
            scale, rule = choose_bvh_scale(nodes)
        except ValueError as exc:
            raise MotionFileError(path, str(exc)) from None
    else:
        rule = "given"
    X = bvh_forward_kinematics(nodes, values) * scale
    keep = [i for i, n in enumerate(nodes) if include_end_sites or not n.end_site]
    skeleton = register_skeleton(_skeleton_from_nodes(nodes, keep))
    positions = X[:, keep]
    offsets = np.array([nodes[c].offset for c in keep])
    bone_lengths = np.array([np.linalg.norm(offsets[b]) * scale for _, b in skeleton.bones])
    rate = 1.0 / dt
    if abs(rate - round(rate)) <= 1e-3 * rate:
        rate = float(round(rate))
    meta = {
        "source": str(path),
        "format": "bvh",
        "scale": scale,
        "scale_rule": rule,
        "frame_time_s": dt,
        "bone_lengths": bone_lengths,
        "bvh_hierarchy": tuple(nodes),  # what write_bvh keeps: offsets, channel order, End Sites
    }
    conf = np.ones(positions.shape[:2])
    return Motion(positions, conf, np.arange(n_frames) / rate, rate, skeleton, meta=meta)


def _hierarchy_for(motion: Motion) -> tuple[list[BvhJoint], float]:
    """The input's hierarchy and scale when the motion came from a BVH file, else a new one (metres)."""
    nodes = motion.meta.get("bvh_hierarchy")
    if nodes is not None:
        names = tuple(n.name for n in nodes if not n.end_site)
        if names == motion.skeleton.joint_names:
            return list(nodes), float(motion.meta.get("scale", 1.0))
    from ..humanoid import build_rig, median_bone_lengths

    skeleton = motion.skeleton
    try:
        rig = build_rig(skeleton, median_bone_lengths(motion.positions, skeleton),
                        reference=_first_complete_frame(motion.positions))
    except ValueError as exc:
        raise ValueError(f"cannot build a BVH hierarchy for skeleton {skeleton.name!r}: {exc}") from None
    out: list[BvhJoint] = []
    index: dict[int, int] = {}
    children = [[c for c in range(len(rig.names)) if rig.parents[c] == k] for k in range(len(rig.names))]

    def add(k: int, parent: int) -> None:
        channels = ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]
        index[k] = len(out)
        out.append(BvhJoint(rig.names[k], parent, rig.offsets[k].copy(), channels))
        for c in children[k]:
            add(c, index[k])
        if not children[k]:
            out.append(BvhJoint(f"{rig.names[k]}_End", index[k], 0.25 * rig.offsets[k], end_site=True))

    add(int(np.flatnonzero(rig.parents < 0)[0]), -1)
    start = 0
    for node in out:
        node.channel_start = start
        start += len(node.channels)
    return out, 1.0


def _first_complete_frame(positions: np.ndarray) -> np.ndarray | None:
    ok = np.isfinite(positions).all(axis=(1, 2))
    return positions[int(np.argmax(ok))] if ok.any() else None


def _write_hierarchy(nodes: list[BvhJoint]) -> list[str]:
    lines = ["HIERARCHY"]
    children = [[c for c, n in enumerate(nodes) if n.parent == k] for k in range(len(nodes))]

    def emit(k: int, depth: int) -> None:
        node, pad = nodes[k], "\t" * depth
        head = "ROOT" if node.parent < 0 else "JOINT"
        lines.append(f"{pad}End Site" if node.end_site else f"{pad}{head} {node.name}")
        lines.append(pad + "{")
        lines.append(pad + "\tOFFSET " + " ".join(f"{v:.6f}" for v in node.offset))
        if not node.end_site:
            lines.append(pad + f"\tCHANNELS {len(node.channels)}" + "".join(f" {c}" for c in node.channels))
        for c in children[k]:
            emit(c, depth + 1)
        lines.append(pad + "}")

    emit(0, 0)
    return lines


def check_bvh_skeleton(skeleton: Skeleton) -> None:
    """ValueError unless ``skeleton``'s bones form one tree (what a BVH hierarchy needs)."""
    from ..core.bone_rotations import parent_array

    if not skeleton.n_bones:
        raise ValueError(f"skeleton {skeleton.name!r} has no bones, so no BVH hierarchy; write .trc instead")
    try:
        parent_array(skeleton.bone_array, skeleton.n_joints)
    except ValueError as exc:
        raise ValueError(f"skeleton {skeleton.name!r} cannot be written as BVH: {exc}; "
                         "write .trc for a marker or graph layout") from None


def write_bvh(motion: Motion, path: str | Path) -> None:
    """Write a motion as BVH, rotations solved from its positions (see module doc).

    ValueError for a skeleton that is not one tree (a pose estimator's graph such as
    COCO-17: write .trc instead) or whose joints are all missing.
    """
    import warnings

    from scipy.spatial.transform import Rotation

    from ..core.bone_rotations import local_positions, solve_local_rotations

    check_bvh_skeleton(motion.skeleton)
    nodes, scale = _hierarchy_for(motion)
    keep = [i for i, n in enumerate(nodes) if not n.end_site]
    remap = {old: new for new, old in enumerate(keep)}
    parents = np.array([remap[nodes[k].parent] if nodes[k].parent >= 0 else -1 for k in keep], dtype=np.intp)
    offsets = np.array([nodes[k].offset for k in keep]) * scale
    joint_index = {n: j for j, n in enumerate(motion.skeleton.joint_names)}
    # a new hierarchy's branch joints sit at their parent joint
    where = np.array([joint_index[nodes[k].name] if nodes[k].name in joint_index else -1 for k in keep])
    for i in np.flatnonzero(where < 0):
        where[i] = where[parents[i]]
    X = motion.positions[:, where]
    if not np.isfinite(X[:, 0]).any():
        raise ValueError(f"{Path(path).name}: the root joint is missing in every frame; nothing to write")
    local = solve_local_rotations(X, parents, offsets)
    translation = local_positions(X, local, parents)
    root_ok = np.isfinite(translation[:, 0]).all(axis=1)
    last = np.maximum.accumulate(np.where(root_ok, np.arange(len(root_ok)), -1))
    translation[:, 0] = translation[np.maximum(last, np.argmax(root_ok)), 0]
    columns = []
    for i, k in enumerate(keep):
        node = nodes[k]
        rot_channels = [c for c in node.channels if c in _ROTATION_CHANNELS]
        euler = {}
        if rot_channels:
            seq = "".join(c[0] for c in rot_channels)  # "ZYX": intrinsic, R = Rz Ry Rx as the reader composes
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # gimbal lock: the angles are still a valid decomposition
                angles = Rotation.from_quat(local[:, i]).as_euler(seq, degrees=True) if len(seq) == 3 else \
                    _partial_euler(Rotation.from_quat(local[:, i]), seq)
            euler = {c: angles[:, a] for a, c in enumerate(rot_channels)}
        t = np.nan_to_num(translation[:, i]) / scale - node.offset
        for c in node.channels:
            columns.append(t[:, _POSITION_CHANNELS[c]] if c in _POSITION_CHANNELS else euler[c])
    values = np.stack(columns, axis=1) if columns else np.zeros((motion.n_frames, 0))
    lines = _write_hierarchy(nodes)
    lines += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {1.0 / motion.rate_hz:.8f}"]
    import io

    buffer = io.StringIO()
    np.savetxt(buffer, values, fmt="%.6f", delimiter=" ")
    Path(path).write_text("\n".join(lines) + "\n" + buffer.getvalue())


def _partial_euler(rotation, seq: str) -> np.ndarray:
    """Angles for fewer than three rotation channels: the full decomposition padded with a free axis, truncated."""
    free = next(a for a in "XYZ" if a not in seq)
    full = seq + free if len(seq) == 2 else seq + "".join(a for a in "XYZ" if a != seq)[:2]
    if len(set(full)) < 3:
        full = seq + "".join(a for a in "XYZ" if a not in seq)
    return rotation.as_euler(full, degrees=True)[:, : len(seq)]
