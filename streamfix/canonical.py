"""One canonical body for every sensor: 20 joints, and the mapping of each supported layout onto it.

Why: the learned prior (``streamfix.prior``) is one model for Kinect v2, Kinect v1 (the
UI-PRMD layout), Azure Kinect, COCO-17 and BlazePose-33 skeletons. Each layout is mapped
onto the canonical joints below; a canonical joint the layout lacks is simply
*unobserved* (the prior was trained on partially observed data and fills it in).

Canonical joints (metres, y up like Kinect camera space and BVH)::

    0 pelvis      midpoint of the two hip joint centres (every layout has both hips)
    1 spine       mid-trunk (Kinect SpineMid / Spine, Azure SPINE_NAVEL)
    2 neck        base of the neck between the shoulders (Kinect v2 SpineShoulder)
    3 head        head centre (Kinect Head; the mean of the ears for COCO/BlazePose)
    4-7  shoulder_l elbow_l wrist_l hand_l      8-11  the same, right
    12-15 hip_l knee_l ankle_l foot_l            16-19 the same, right

``LAYOUTS[name].to_canonical`` gives each canonical joint as a weighted mean of layout
joints (observed only where every contributing joint is observed);
``LAYOUTS[name].anchors`` names, for each layout joint, the canonical joint it moves
with, and ``exact`` marks the layout joints that *are* a canonical joint. Going back
(:func:`from_canonical`) an exact joint takes the canonical value; any other joint (hand
tips, thumbs, face points, SpineBase, ...) is placed at anchor + k (anchor - anchor's
parent) + d, with the scalar k and offset d fitted by least squares on the frames where
that joint was observed (a hand tip extends the wrist-hand segment as the hand turns); a
joint never observed sits at its anchor.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .skeletons import AZURE_KINECT, COCO_17, KINECT_V2, MEDIAPIPE_POSE

__all__ = [
    "CANONICAL_JOINTS",
    "CANONICAL_BONES",
    "CANONICAL_LIMBS",
    "CANONICAL_MIRROR",
    "mirrored",
    "CANONICAL_SCALE_BONES",
    "CANONICAL_ROOT",
    "CANONICAL_HIPS",
    "LAYOUTS",
    "Layout",
    "KINECT_V1_UIPRMD_JOINTS",
    "COCO17_JOINTS",
    "layout_for_joint_count",
    "get_layout",
    "to_canonical",
    "from_canonical",
]

_SIDES = ("l", "r")
CANONICAL_JOINTS: tuple[str, ...] = (
    "pelvis", "spine", "neck", "head",
    "shoulder_l", "elbow_l", "wrist_l", "hand_l",
    "shoulder_r", "elbow_r", "wrist_r", "hand_r",
    "hip_l", "knee_l", "ankle_l", "foot_l",
    "hip_r", "knee_r", "ankle_r", "foot_r",
)
_CI = {n: i for i, n in enumerate(CANONICAL_JOINTS)}
_PARENT = {
    "spine": "pelvis", "neck": "spine", "head": "neck",
    **{f"shoulder_{s}": "neck" for s in _SIDES}, **{f"elbow_{s}": f"shoulder_{s}" for s in _SIDES},
    **{f"wrist_{s}": f"elbow_{s}" for s in _SIDES}, **{f"hand_{s}": f"wrist_{s}" for s in _SIDES},
    **{f"hip_{s}": "pelvis" for s in _SIDES}, **{f"knee_{s}": f"hip_{s}" for s in _SIDES},
    **{f"ankle_{s}": f"knee_{s}" for s in _SIDES}, **{f"foot_{s}": f"ankle_{s}" for s in _SIDES},
}
#: (parent, child) index pairs, 19 bones, parents first.
CANONICAL_BONES = np.array([(_CI[_PARENT[n]], _CI[n]) for n in CANONICAL_JOINTS[1:]], dtype=np.intp)
CANONICAL_ROOT = _CI["pelvis"]
# parent of each canonical joint (the root is its own)
_PARENT_INDEX = np.array([_CI[_PARENT.get(n, n)] for n in CANONICAL_JOINTS], dtype=np.intp)
CANONICAL_HIPS = (_CI["hip_l"], _CI["hip_r"])
#: The paper's structured masks (Lohit et al. Table 3): a whole arm or leg, 4 joints each.
CANONICAL_LIMBS = {
    "right_arm": tuple(_CI[f"{j}_r"] for j in ("shoulder", "elbow", "wrist", "hand")),
    "left_arm": tuple(_CI[f"{j}_l"] for j in ("shoulder", "elbow", "wrist", "hand")),
    "right_leg": tuple(_CI[f"{j}_r"] for j in ("hip", "knee", "ankle", "foot")),
    "left_leg": tuple(_CI[f"{j}_l"] for j in ("hip", "knee", "ankle", "foot")),
}
#: Left/right swap for mirroring: joint j of the mirrored body is joint CANONICAL_MIRROR[j] (x negated).
CANONICAL_MIRROR = np.array(
    [_CI[n[:-1] + {"l": "r", "r": "l"}[n[-1]]] if n[-2:] in ("_l", "_r") else _CI[n] for n in CANONICAL_JOINTS],
    dtype=np.intp,
)
_FLIP_X = np.array([-1.0, 1.0, 1.0])


def mirrored(positions: np.ndarray, observed: np.ndarray, mirror: np.ndarray = CANONICAL_MIRROR) -> tuple[np.ndarray, np.ndarray]:
    """The left/right mirror image of ``(..., T, J, 3)`` metre positions and their ``(..., T, J)``
    mask: x negated, joint j taken from ``mirror[j]``. Its own inverse."""
    return positions[..., mirror, :] * _FLIP_X, observed[..., mirror]


#: Child joints of the bones used for the body-scale estimate: trunk, shoulders, hips and long limb bones
#: (hands and feet are short and noisy on depth sensors).
CANONICAL_SCALE_BONES = tuple(
    _CI[n] for n in ("spine", "neck", "shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l", "wrist_r",
                     "hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r")
)

# UI-PRMD's Kinect v1 layout (paired/README.md; registered as skeleton ``kinect_v1_uiprmd`` by the
# paired-data module). Its Neck and Chest coincide at the base of the neck; HeadTip is the sensor's head.
KINECT_V1_UIPRMD_JOINTS = (
    "Waist", "Spine", "Chest", "Neck", "Head", "HeadTip", "LCollar", "LShoulder", "LElbow", "LWrist",
    "RCollar", "RShoulder", "RElbow", "RWrist", "LHip", "LKnee", "LAnkle", "LFoot", "RHip", "RKnee",
    "RAnkle", "RFoot",
)
COCO17_JOINTS = COCO_17.joint_names


@dataclass(frozen=True)
class Layout:
    """A sensor layout's joint names and how they map to and from the canonical joints."""

    name: str
    joints: tuple[str, ...]
    to_canonical: dict  # canonical joint -> {layout joint: weight}, weights sum to 1
    anchors: dict  # layout joint -> canonical joint it moves with

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def weights(self) -> np.ndarray:
        """(20, J) matrix W: canonical = W @ layout positions."""
        return _matrices(self).weights

    @property
    def anchor_index(self) -> np.ndarray:
        """(J,) canonical index each layout joint moves with."""
        return _matrices(self).anchor

    @property
    def exact(self) -> np.ndarray:
        """(J,) bool: the layout joint is itself a canonical joint (weight 1, one-to-one)."""
        return _matrices(self).exact

    @property
    def covered(self) -> np.ndarray:
        """(20,) bool: the canonical joints this layout can observe."""
        return _matrices(self).covered


class _Maps(NamedTuple):
    """A layout's index maps, built once per layout name (the prior maps every streamed window)."""

    weights: np.ndarray  # (20, J): canonical = W @ layout positions
    anchor: np.ndarray  # (J,) canonical joint each layout joint moves with
    exact: np.ndarray  # (J,) bool: the layout joint is a canonical joint
    used_t: np.ndarray  # (J, 20) float 0/1: the layout joint contributes to the canonical one
    covered: np.ndarray  # (20,) bool: canonical joints the layout can observe
    approx: np.ndarray  # (A,) the layout joints that are not exact


_MAPS: dict[str, _Maps] = {}


def _matrices(layout: Layout) -> _Maps:
    """The ``_Maps`` of a layout, computed once per layout name."""
    if layout.name not in _MAPS:
        _MAPS[layout.name] = _build_maps(layout)
    return _MAPS[layout.name]


def _build_maps(layout: Layout) -> _Maps:
    idx = {n: i for i, n in enumerate(layout.joints)}
    w = np.zeros((len(CANONICAL_JOINTS), len(layout.joints)))
    for cj, parts in layout.to_canonical.items():
        for lj, wt in parts.items():
            w[_CI[cj], idx[lj]] += wt
    anchor = np.array([_CI[layout.anchors[j]] for j in layout.joints], dtype=np.intp)
    exact = np.zeros(len(layout.joints), dtype=bool)
    for cj, parts in layout.to_canonical.items():
        if len(parts) == 1:
            (lj, wt), = parts.items()
            exact[idx[lj]] = wt == 1.0 and layout.anchors[lj] == cj
    used = np.abs(w) > 0
    maps = _Maps(w, anchor, exact, used.T.astype(np.float64), used.any(axis=1), np.flatnonzero(~exact))
    for a in maps:
        a.setflags(write=False)  # shared by every caller
    return maps


def _layout(name: str, joints, to_canonical: dict, extra_anchors: dict) -> Layout:
    anchors = {lj: cj for cj, parts in to_canonical.items() if len(parts) == 1 for lj in parts}
    anchors.update(extra_anchors)
    missing = [j for j in joints if j not in anchors]
    if missing:
        raise ValueError(f"layout {name}: no canonical anchor for {missing}")
    return Layout(name, tuple(joints), to_canonical, anchors)


def _sided(fmt: dict[str, str], sides: dict[str, str]) -> dict:
    """{canonical_side: {layout name: 1}} for a table of canonical stem -> layout name pattern with {S}."""
    return {f"{stem}_{s}": {pat.format(S=sides[s]): 1.0} for stem, pat in fmt.items() for s in _SIDES}


_K2 = {"Shoulder": "shoulder", "Elbow": "elbow", "Wrist": "wrist", "Hand": "hand", "Hip": "hip", "Knee": "knee",
       "Ankle": "ankle", "Foot": "foot"}
_KINECT_V2 = _layout(
    "kinect_v2",
    KINECT_V2.joint_names,
    {"pelvis": {"HipLeft": 0.5, "HipRight": 0.5}, "spine": {"SpineMid": 1.0}, "neck": {"SpineShoulder": 1.0},
     "head": {"Head": 1.0},
     **_sided({v: f"{k}{{S}}" for k, v in _K2.items()}, {"l": "Left", "r": "Right"})},
    {"SpineBase": "pelvis", "Neck": "neck", "HandTipLeft": "hand_l", "ThumbLeft": "hand_l",
     "HandTipRight": "hand_r", "ThumbRight": "hand_r"},
)
_AZURE = _layout(
    "azure_kinect",
    AZURE_KINECT.joint_names,
    {"pelvis": {"HIP_LEFT": 0.5, "HIP_RIGHT": 0.5}, "spine": {"SPINE_NAVEL": 1.0}, "neck": {"NECK": 1.0},
     "head": {"HEAD": 1.0},
     **_sided({v: f"{k.upper()}_{{S}}" for k, v in _K2.items()}, {"l": "LEFT", "r": "RIGHT"})},
    {"PELVIS": "pelvis", "SPINE_CHEST": "spine", "CLAVICLE_LEFT": "neck", "CLAVICLE_RIGHT": "neck",
     "HANDTIP_LEFT": "hand_l", "THUMB_LEFT": "hand_l", "HANDTIP_RIGHT": "hand_r", "THUMB_RIGHT": "hand_r",
     "NOSE": "head", "EYE_LEFT": "head", "EAR_LEFT": "head", "EYE_RIGHT": "head", "EAR_RIGHT": "head"},
)
_KINECT_V1 = _layout(
    "kinect_v1_uiprmd",
    KINECT_V1_UIPRMD_JOINTS,
    {"pelvis": {"LHip": 0.5, "RHip": 0.5}, "spine": {"Spine": 1.0}, "neck": {"Neck": 1.0},
     "head": {"HeadTip": 1.0},
     **_sided({v: f"{{S}}{k}" for k, v in _K2.items() if v != "hand"}, {"l": "L", "r": "R"})},
    {"Waist": "pelvis", "Chest": "neck", "Head": "head", "LCollar": "neck", "RCollar": "neck"},
)
_COCO_STEMS = {"shoulder": "shoulder", "elbow": "elbow", "wrist": "wrist", "hip": "hip", "knee": "knee",
               "ankle": "ankle"}
_COCO = _layout(
    "coco17",
    COCO17_JOINTS,
    {"pelvis": {"left_hip": 0.5, "right_hip": 0.5}, "neck": {"left_shoulder": 0.5, "right_shoulder": 0.5},
     "head": {"left_ear": 0.5, "right_ear": 0.5},
     **_sided({v: f"{{S}}_{k}" for k, v in _COCO_STEMS.items()}, {"l": "left", "r": "right"})},
    {"nose": "head", "left_eye": "head", "right_eye": "head", "left_ear": "head", "right_ear": "head"},
)
_MP_FACE = ("nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
            "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right")
_MEDIAPIPE = _layout(
    "mediapipe_pose",
    MEDIAPIPE_POSE.joint_names,
    {"pelvis": {"left_hip": 0.5, "right_hip": 0.5}, "neck": {"left_shoulder": 0.5, "right_shoulder": 0.5},
     "head": {"left_ear": 0.5, "right_ear": 0.5},
     # mid-hand: half-way from the wrist to the knuckles (index and pinky MCP)
     "hand_l": {"left_wrist": 0.5, "left_index": 0.25, "left_pinky": 0.25},
     "hand_r": {"right_wrist": 0.5, "right_index": 0.25, "right_pinky": 0.25},
     **_sided({**{v: f"{{S}}_{k}" for k, v in _COCO_STEMS.items()}, "foot": "{S}_foot_index"},
              {"l": "left", "r": "right"})},
    {**{f: "head" for f in _MP_FACE}, "left_pinky": "hand_l", "left_index": "hand_l", "left_thumb": "hand_l",
     "right_pinky": "hand_r", "right_index": "hand_r", "right_thumb": "hand_r", "left_heel": "ankle_l",
     "right_heel": "ankle_r"},
)
_CANONICAL = _layout("canonical", CANONICAL_JOINTS, {n: {n: 1.0} for n in CANONICAL_JOINTS}, {})

#: Every supported layout by name (joint counts are all different, see ``layout_for_joint_count``).
LAYOUTS: dict[str, Layout] = {l.name: l for l in (_CANONICAL, _KINECT_V2, _AZURE, _KINECT_V1, _COCO, _MEDIAPIPE)}


def get_layout(name: str) -> Layout:
    """The layout called ``name``; the error lists the known ones."""
    try:
        return LAYOUTS[name]
    except KeyError:
        raise KeyError(f"no canonical mapping for layout {name!r}; known layouts: {', '.join(sorted(LAYOUTS))}") from None


def layout_for_joint_count(n_joints: int) -> Layout:
    """The layout with ``n_joints`` joints (20 canonical, 25 Kinect v2, 32 Azure, 22 Kinect v1, 17 COCO, 33 BlazePose)."""
    for layout in LAYOUTS.values():
        if layout.n_joints == n_joints:
            return layout
    counts = ", ".join(f"{l.n_joints} ({l.name})" for l in LAYOUTS.values())
    raise ValueError(f"no canonical mapping for a {n_joints}-joint skeleton; supported joint counts: {counts}")


def _check(positions: np.ndarray, observed: np.ndarray, n_joints: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(positions, dtype=np.float64)
    if x.shape[-2:] != (n_joints, 3):
        raise ValueError(f"{what}: expected (..., {n_joints}, 3) positions, got {x.shape}")
    obs = np.asarray(observed, dtype=bool)
    if obs.shape != x.shape[:-1]:
        raise ValueError(f"{what}: expected an observed mask of shape {x.shape[:-1]}, got {obs.shape}")
    return x, obs & np.isfinite(x).all(axis=-1)


def to_canonical(positions: np.ndarray, observed: np.ndarray, layout: str | Layout) -> tuple[np.ndarray, np.ndarray]:
    """Layout positions (..., J, 3) m and mask (..., J) -> canonical (..., 20, 3) (NaN where unobserved) and mask."""
    lay = get_layout(layout) if isinstance(layout, str) else layout
    x, obs = _check(positions, observed, lay.n_joints, f"to_canonical({lay.name})")
    return _to_canonical(x, obs, _matrices(lay))


def _to_canonical(x: np.ndarray, obs: np.ndarray, maps: _Maps) -> tuple[np.ndarray, np.ndarray]:
    """``to_canonical`` of validated input (``_check``'s output)."""
    out = maps.weights @ np.where(obs[..., None], x, 0.0)  # (C, J) x (..., J, 3): matmul, not einsum (latency)
    # a canonical joint is observed where every contributing layout joint is
    cobs = maps.covered & ~((~obs).astype(np.float64) @ maps.used_t > 0)
    out[~cobs] = np.nan
    return out, cobs


def from_canonical(
    canonical: np.ndarray,
    layout: str | Layout,
    positions: np.ndarray | None = None,
    observed: np.ndarray | None = None,
) -> np.ndarray:
    """Canonical estimate (T, 20, 3) -> the layout's joints (T, J, 3) m.

    Exact joints take the canonical value; every other joint is placed at
    anchor + k (anchor - anchor's parent) + d with k, d fitted on the frames of
    ``positions``/``observed`` (the layout's own data, (T, J, 3)/(T, J)) where it was
    observed (module doc), or at its anchor when it never was.
    """
    lay = get_layout(layout) if isinstance(layout, str) else layout
    c = np.asarray(canonical, dtype=np.float64)
    if c.shape[-2:] != (len(CANONICAL_JOINTS), 3):
        raise ValueError(f"from_canonical: expected (..., {len(CANONICAL_JOINTS)}, 3), got {c.shape}")
    if positions is None:
        return c[..., lay.anchor_index, :]
    x, obs = _check(positions, observed, lay.n_joints, f"from_canonical({lay.name})")
    return _from_canonical(c, _matrices(lay), x, obs)


def _from_canonical(c: np.ndarray, maps: _Maps, x: np.ndarray, obs: np.ndarray,
                    joints: np.ndarray | None = None) -> np.ndarray:
    """``from_canonical`` of a (..., 20, 3) float array and validated layout data (``_check``'s output).

    ``joints`` (J,) bool: only these need their exact place; the others that are not canonical joints
    are left at their anchors (a caller that reads a few joints skips the others' fits)."""
    out = c[..., maps.anchor, :]  # a copy (fancy indexing)
    approx = maps.approx if joints is None else maps.approx[joints[maps.approx]]
    if approx.size:
        # x_j ~ a + k u + d: a = anchor, u = a - (anchor's parent), k and d fitted on the observed frames,
        # so a hand tip stays on the line of the hand segment as the hand turns
        a = out[..., approx, :]
        u = a - c[..., _PARENT_INDEX[maps.anchor[approx]], :]
        o = obs[..., approx, None]
        diff = np.where(o, x[..., approx, :] - a, 0.0)
        uu = np.where(o, u, 0.0)
        n = np.maximum(o.sum(axis=-3), 1)  # (..., A, 1)
        u_mean, d_mean = uu.sum(axis=-3) / n, diff.sum(axis=-3) / n
        du = np.where(o, u - u_mean[..., None, :, :], 0.0)
        cov = np.einsum("...tak,...tak->...a", du, diff - d_mean[..., None, :, :])
        var = np.einsum("...tak,...tak->...a", du, du)
        # k within +-3 segment lengths: a segment that barely turned in the window says little about k
        k = np.minimum(np.maximum(np.where(var > 1e-6, cov / np.maximum(var, 1e-12), 0.0), -3.0), 3.0)  # (..., A)
        d = d_mean - k[..., None] * u_mean
        out[..., approx, :] = a + k[..., None, :, None] * u + d[..., None, :, :]
    return out
