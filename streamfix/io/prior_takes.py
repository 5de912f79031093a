"""Training and evaluation takes for the learned prior (``streamfix.prior``), read from the shared recordings (numpy only).

A :class:`Take` is one recording as joint positions (N, J, 3) in metres, y up, NaN
where unobserved, with its observation mask, rate (Hz), source and *group* (the person
or take that held-out splits keep together). Sources and how joints are obtained:

* ``bvh`` (CMU, Xia): retargeted to Kinect v2 (``streamfix.io.retarget``), all observed;
* ``kinect_v2`` CSV: tracked joints observed, inferred ones not (they are the SDK's guesses);
* ``c3d_markers`` (CMU full-body marker set): Kinect v2 joints approximated from
  markers (``_CMU_MARKERS_TO_KINECT``);
* ``uiprmd_vicon``: UI-PRMD's Plug-in-Gait markers (``paired/uiprmd``, 100 Hz, z up)
  turned into the canonical joint centres by :func:`plug_in_gait_joints`;
* ``uiprmd_kinect_v1``: UI-PRMD's Kinect v1 skeletons (30 Hz), partially observed: the
  legs are marked unobserved in the deep squat (m01) and sit-to-stand (m05), where
  the paired README measured the sensor's legs failing by 24-49 cm.

:func:`canonical_takes` maps any of them onto ``streamfix.canonical``'s 20 joints.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..canonical import CANONICAL_JOINTS, to_canonical

__all__ = [
    "Take",
    "load_take",
    "marker_take",
    "PLUG_IN_GAIT_MARKERS",
    "plug_in_gait_joints",
    "uiprmd_takes",
    "canonical_take",
    "canonical_takes",
    "UIPRMD_FILE",
]

UIPRMD_FILE = Path("paired") / "uiprmd" / "uiprmd_s01-s06.npz"
PLUG_IN_GAIT_MARKERS = (
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA RELB RFRM RWRA RWRB "
    "RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE"
).split()
_UIPRMD_BAD_LEGS = (1, 5)  # movements where the Kinect v1 legs fail (paired/README.md)


@dataclass
class Take:
    name: str
    positions: np.ndarray  # (N, J, 3) m, NaN where unobserved
    observed: np.ndarray  # (N, J) bool
    rate_hz: float
    source: str  # "bvh", "kinect_v2", "c3d_markers", "uiprmd_vicon", "uiprmd_kinect_v1"
    group: str = field(default="")  # person/take kept together by held-out splits (default: the name)

    def __post_init__(self) -> None:
        self.group = self.group or self.name

    @property
    def duration_s(self) -> float:
        return self.positions.shape[0] / self.rate_hz


def load_take(path: str | Path) -> Take:
    """One file as a Kinect v2 take: BVH retargeted (all observed), Kinect CSV with tracked joints observed."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        from streamfix.io.bvh import read_bvh
        from streamfix.io.retarget import bvh_to_kinect_v2

        motion = bvh_to_kinect_v2(read_bvh(path))
        observed = motion.observed.copy()
        source = "bvh"
    elif suffix == ".csv":
        from streamfix.io.kinect_csv import read_kinect_csv

        motion = read_kinect_csv(path)
        observed = motion.confidence >= 1.0  # tracked only
        source = "kinect_v2"
    else:
        raise ValueError(f"{path}: expected a .bvh or Kinect v2 .csv file, got {suffix!r}")
    if motion.n_joints != 25:
        raise ValueError(f"{path}: expected the 25 Kinect v2 joints, got {motion.n_joints}")
    positions = motion.positions.copy()
    positions[~observed] = np.nan
    return Take(path.stem, positions, observed, motion.rate_hz, source)


# CMU full-body marker set -> Kinect v2 joints (approximate joint positions from surface
# markers; documented so the approximation is visible): each Kinect joint is a weighted
# sum of markers, weights summing to 1.
_CMU_MARKERS_TO_KINECT = {
    "SpineBase": {"LFWT": 0.25, "RFWT": 0.25, "LBWT": 0.25, "RBWT": 0.25},  # pelvis centre
    "SpineMid": {"T10": 0.5, "STRN": 0.5},
    "SpineShoulder": {"C7": 0.5, "CLAV": 0.5},
    "Neck": {"C7": 0.35, "CLAV": 0.35, "LFHD": 0.075, "RFHD": 0.075, "LBHD": 0.075, "RBHD": 0.075},
    "Head": {"LFHD": 0.25, "RFHD": 0.25, "LBHD": 0.25, "RBHD": 0.25},
    # hip joint centre: pelvis centre + 0.325 (same-side waist midpoint - other-side midpoint), ~8 cm
    # (then SpineBase and both hips are moved 8 cm down the trunk: waist markers sit on the iliac crest)
    "HipLeft": {"LFWT": 0.4125, "LBWT": 0.4125, "RFWT": 0.0875, "RBWT": 0.0875},
    "HipRight": {"RFWT": 0.4125, "RBWT": 0.4125, "LFWT": 0.0875, "LBWT": 0.0875},
    "KneeLeft": {"LKNE": 1.0}, "KneeRight": {"RKNE": 1.0},
    "AnkleLeft": {"LANK": 1.0}, "AnkleRight": {"RANK": 1.0},
    "FootLeft": {"LTOE": 0.5, "LMT5": 0.5}, "FootRight": {"RTOE": 0.5, "RMT5": 0.5},
    "ShoulderLeft": {"LSHO": 1.0}, "ShoulderRight": {"RSHO": 1.0},
    "ElbowLeft": {"LELB": 1.0}, "ElbowRight": {"RELB": 1.0},
    "WristLeft": {"LWRA": 0.5, "LWRB": 0.5}, "WristRight": {"RWRA": 0.5, "RWRB": 0.5},
    # hand = 60 % and hand tip = 160 % of the way from the wrist centre to the knuckle marker
    "HandLeft": {"LWRA": 0.2, "LWRB": 0.2, "LFIN": 0.6}, "HandRight": {"RWRA": 0.2, "RWRB": 0.2, "RFIN": 0.6},
    "HandTipLeft": {"LWRA": -0.3, "LWRB": -0.3, "LFIN": 1.6}, "HandTipRight": {"RWRA": -0.3, "RWRB": -0.3, "RFIN": 1.6},
    # thumb: from the thumb-side wrist marker 80 % of the wrist-to-knuckle vector
    "ThumbLeft": {"LWRA": 0.6, "LWRB": -0.4, "LFIN": 0.8}, "ThumbRight": {"RWRA": 0.6, "RWRB": -0.4, "RFIN": 0.8},
}


def marker_take(path: str | Path) -> Take | None:
    """A CMU full-body marker C3D as a Kinect v2 take (``_CMU_MARKERS_TO_KINECT``), z-up turned y-up; None if not that marker set."""
    from streamfix.io.c3d import read_c3d
    from streamfix.skeletons import KINECT_V2

    path = Path(path)
    motion = read_c3d(path)
    names = {n.split(":")[-1].upper(): i for i, n in enumerate(motion.skeleton.joint_names)}
    needed = {m for w in _CMU_MARKERS_TO_KINECT.values() for m in w}
    if not needed <= set(names):
        return None
    weights = np.zeros((KINECT_V2.n_joints, motion.n_joints))
    for joint, wts in _CMU_MARKERS_TO_KINECT.items():
        for marker, wgt in wts.items():
            weights[KINECT_V2.index(joint), names[marker]] += wgt
    pos = np.einsum("km,tmc->tkc", weights, np.nan_to_num(motion.positions))
    trunk = pos[:, KINECT_V2.index("SpineShoulder")] - pos[:, KINECT_V2.index("SpineBase")]
    down = -trunk / np.maximum(np.linalg.norm(trunk, axis=-1, keepdims=True), 1e-9)
    for name in ("SpineBase", "HipLeft", "HipRight"):
        pos[:, KINECT_V2.index(name)] += 0.08 * down
    used = np.abs(weights) > 0
    observed = (motion.observed[:, None, :] | ~used[None]).all(axis=2)
    pos = pos[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # z-up -> y-up, right-handed
    pos[~observed] = np.nan
    return Take(path.stem, pos, observed, motion.rate_hz, "c3d_markers")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


def plug_in_gait_joints(markers: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical joint centres (T, 20, 3) m, y up, and mask from Plug-in-Gait markers (T, 39, 3) m, z up.

    * pelvis frame from the ASIS/PSIS markers; hip joint centres by Harrington et al.
      (J. Biomech. 2007) from pelvic width PW and depth PD, in mm from the mid-ASIS:
      anterior -0.24 PD - 9.9, superior -0.30 PW - 10.9, lateral 0.33 PW + 7.3;
      pelvis = their midpoint;
    * knee / ankle centres: the lateral KNE / ANK marker moved medially (along the pelvis'
      left-right axis) by half a typical knee (10 cm) / ankle (7 cm) width plus the 7 mm
      marker radius;
    * shoulder centre: the acromion marker SHO moved 5 cm down the trunk (neck -> pelvis);
    * elbow = ELB (lateral epicondyle; no width is recorded to move it medially);
      wrist = mean of WRA, WRB; hand = half-way from the wrist to FIN (the knuckle);
      foot = TOE (2nd metatarsal head); head = mean of the 4 head markers;
      neck = mean of C7 and CLAV; spine = mean of T10 and STRN.

    A joint is observed where every marker it uses is (a lost Vicon marker is (0, 0, 0)).
    """
    m = np.asarray(markers, dtype=np.float64)
    if m.shape[1:] != (len(PLUG_IN_GAIT_MARKERS), 3):
        raise ValueError(f"expected (T, {len(PLUG_IN_GAIT_MARKERS)}, 3) Plug-in-Gait markers, got {m.shape}")
    ok = np.asarray(observed, dtype=bool)
    idx = {n: i for i, n in enumerate(PLUG_IN_GAIT_MARKERS)}

    def mk(*names):
        return m[:, [idx[n] for n in names]].mean(axis=1), ok[:, [idx[n] for n in names]].all(axis=1)

    lasi, rasi, lpsi, rpsi = (m[:, idx[n]] for n in ("LASI", "RASI", "LPSI", "RPSI"))
    pel_ok = ok[:, [idx[n] for n in ("LASI", "RASI", "LPSI", "RPSI")]].all(axis=1)
    mid_asis, mid_psis = 0.5 * (lasi + rasi), 0.5 * (lpsi + rpsi)
    right = _unit(rasi - lasi)
    fwd = mid_asis - mid_psis
    fwd = _unit(fwd - (fwd * right).sum(-1, keepdims=True) * right)
    up = np.cross(right, fwd)
    pw = np.linalg.norm(rasi - lasi, axis=-1, keepdims=True) * 1e3  # mm
    pd = np.linalg.norm(mid_asis - mid_psis, axis=-1, keepdims=True) * 1e3
    base = mid_asis + 1e-3 * ((-0.24 * pd - 9.9) * fwd + (-0.30 * pw - 10.9) * up)
    lat = 1e-3 * (0.33 * pw + 7.3) * right
    hip_r, hip_l = base + lat, base - lat
    neck, neck_ok = mk("C7", "CLAV")
    down = _unit(0.5 * (hip_l + hip_r) - neck)
    joints: dict[str, tuple[np.ndarray, np.ndarray]] = {
        "pelvis": (base, pel_ok), "hip_l": (hip_l, pel_ok), "hip_r": (hip_r, pel_ok),
        "spine": mk("T10", "STRN"), "neck": (neck, neck_ok), "head": mk("LFHD", "RFHD", "LBHD", "RBHD"),
    }
    for s, sign in (("l", 1.0), ("r", -1.0)):  # medial = +right for the left side
        p = s.upper()
        sho, sho_ok = mk(f"{p}SHO")
        joints[f"shoulder_{s}"] = (sho + 0.05 * down, sho_ok & neck_ok & pel_ok)
        joints[f"elbow_{s}"] = mk(f"{p}ELB")
        wrist, wrist_ok = mk(f"{p}WRA", f"{p}WRB")
        joints[f"wrist_{s}"] = (wrist, wrist_ok)
        fin, fin_ok = mk(f"{p}FIN")
        joints[f"hand_{s}"] = (0.5 * (wrist + fin), wrist_ok & fin_ok)
        knee, knee_ok = mk(f"{p}KNE")
        joints[f"knee_{s}"] = (knee + sign * 0.057 * right, knee_ok & pel_ok)
        ankle, ankle_ok = mk(f"{p}ANK")
        joints[f"ankle_{s}"] = (ankle + sign * 0.042 * right, ankle_ok & pel_ok)
        joints[f"foot_{s}"] = mk(f"{p}TOE")
    pos = np.stack([joints[n][0] for n in CANONICAL_JOINTS], axis=1)
    obs = np.stack([joints[n][1] for n in CANONICAL_JOINTS], axis=1)
    pos = pos[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # z-up -> y-up, right-handed
    pos[~obs] = np.nan
    return pos, obs


def uiprmd_takes(
    data_dir: str | Path, kind: str = "vicon", subjects: tuple[int, ...] | None = None
) -> list[Take]:
    """UI-PRMD repetitions as takes (one per repetition, group ``uiprmd_sSS``), sorted by key.

    ``kind="vicon"``: canonical joints from the markers (:func:`plug_in_gait_joints`), 100 Hz;
    ``kind="kinect_v1"``: the Kinect v1 skeleton (22 joints, ``kinect_v1_uiprmd`` layout) at its
    fitted rate, legs unobserved in m01/m05 (module doc). ``subjects``: e.g. (1, 2); None = all.
    """
    if kind not in ("vicon", "kinect_v1"):
        raise ValueError(f"kind must be 'vicon' or 'kinect_v1', got {kind!r}")
    path = Path(data_dir) / UIPRMD_FILE
    if not path.is_file():
        raise FileNotFoundError(f"UI-PRMD recordings not found at {path}")
    from ..canonical import KINECT_V1_UIPRMD_JOINTS

    z = np.load(path)
    unit = float(z["vicon_unit_m"])
    keys = sorted(k[len("vicon_"):] for k in z.files if k.startswith("vicon_") and k.count("_") == 4)
    legs = [KINECT_V1_UIPRMD_JOINTS.index(n) for n in KINECT_V1_UIPRMD_JOINTS if n[1:] in ("Knee", "Ankle", "Foot")]
    takes = []
    for key in keys:  # repetitions, not frames
        cset, mov, subj, rep = key.split("_")
        s = int(subj[1:])
        if subjects is not None and s not in subjects:
            continue
        name, group = f"uiprmd_{subj}_{cset}_{mov}_{rep}", f"uiprmd_{subj}"
        if kind == "vicon":
            raw = z[f"vicon_{key}"]
            obs = (raw != 0).any(axis=-1)
            pos, cobs = plug_in_gait_joints(raw.astype(np.float64) * unit, obs)
            takes.append(Take(name, pos, cobs, 100.0, "uiprmd_vicon", group))
        else:
            pos = z[f"kinect_{key}"].astype(np.float64)
            obs = np.isfinite(pos).all(axis=-1)
            if int(mov[1:]) in _UIPRMD_BAD_LEGS:
                obs[:, legs] = False
            pos[~obs] = np.nan
            rate = float(z[f"fs_{key}"]) if f"fs_{key}" in z.files else 30.0  # not every repetition was aligned
            takes.append(Take(name, pos, obs, rate, "uiprmd_kinect_v1", group))
    return takes


def canonical_take(take: Take, layout: str) -> Take:
    """``take`` (in ``layout``) with its joints mapped onto the canonical 20 (``streamfix.canonical``)."""
    pos, obs = to_canonical(take.positions, take.observed, layout)
    return Take(take.name, pos, obs, take.rate_hz, take.source, take.group)


def canonical_takes(data_dir: str | Path, *, markers: bool = True, kinect_v1: bool = False) -> list[Take]:
    """Every licence-clean training source under ``data_dir`` as canonical takes.

    CMU and Xia BVH, Kinect v2 CSV, the CMU-marker C3D takes (``markers``; other C3D
    files have no stated licence and another marker set), UI-PRMD Vicon and (``kinect_v1``)
    UI-PRMD Kinect v1.
    """
    data_dir = Path(data_dir)
    paths = sorted(data_dir.glob("*_bvh/*.bvh")) + sorted(data_dir.glob("kinect_v2/*.csv"))
    if not paths:
        raise FileNotFoundError(f"no *_bvh/*.bvh or kinect_v2/*.csv files under {data_dir}")
    takes = [canonical_take(load_take(p), "kinect_v2") for p in paths]
    if markers:
        for p in sorted(data_dir.glob("c3d/*.c3d")):
            t = marker_take(p)
            if t is not None:
                takes.append(canonical_take(t, "kinect_v2"))
    takes += uiprmd_takes(data_dir, "vicon")
    if kinect_v1:
        takes += [canonical_take(t, "kinect_v1_uiprmd") for t in uiprmd_takes(data_dir, "kinect_v1")]
    return takes
