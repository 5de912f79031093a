"""A private reader of one UI-PRMD paired repetition (``uiprmd_s01-s06.npz:KEY``).

Stand-in until ``streamfix.io.paired`` lands; swap :func:`read_paired` for its loader
then. Layout (``../shared/data/paired/README.md``): ``kinect_<key>`` (T, 22, 3) metres,
Kinect v1 camera frame, nominally 30 Hz; ``vicon_<key>`` (Tv, 39, 3) int16 in units of
``vicon_unit_m`` at 100 Hz, a lost marker stored as (0, 0, 0); Kinect frame ``i`` is at
Vicon time ``i / fs + off`` and ``R @ k + t`` maps Kinect into Vicon coordinates. The
reference joint is the mean of its markers, sampled at the Kinect frame times by linear
interpolation and mapped into the Kinect frame (``R^T (v - t)``), so raw, cleaned and
reference live in one space.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..motion import Motion
from ..skeletons import Skeleton

__all__ = ["parse_paired_spec", "read_paired"]

JOINTS = ("Waist", "Spine", "Chest", "Neck", "Head", "HeadTip", "LCollar", "LShoulder", "LElbow", "LWrist",
          "RCollar", "RShoulder", "RElbow", "RWrist", "LHip", "LKnee", "LAnkle", "LFoot", "RHip", "RKnee",
          "RAnkle", "RFoot")
PARENTS = (-1, 0, 1, 2, 3, 4, 2, 6, 7, 8, 2, 10, 11, 12, 0, 14, 15, 16, 0, 18, 19, 20)
MARKERS = ("LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA RELB RFRM "
           "RWRA RWRB RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE").split()
REFERENCE = {
    "HeadTip": ("LFHD", "RFHD", "LBHD", "RBHD"), "Neck": ("C7", "CLAV"), "Waist": ("LASI", "RASI", "LPSI", "RPSI"),
    **{f"{s}Shoulder": (f"{s}SHO",) for s in "LR"}, **{f"{s}Elbow": (f"{s}ELB",) for s in "LR"},
    **{f"{s}Wrist": (f"{s}WRA", f"{s}WRB") for s in "LR"}, **{f"{s}Hip": (f"{s}ASI", f"{s}PSI") for s in "LR"},
    **{f"{s}Knee": (f"{s}KNE",) for s in "LR"}, **{f"{s}Ankle": (f"{s}ANK",) for s in "LR"},
    **{f"{s}Foot": (f"{s}TOE",) for s in "LR"},
}
SKELETON = Skeleton("uiprmd_kinect_v1", JOINTS, tuple((p, c) for c, p in enumerate(PARENTS) if p >= 0))
VICON_RATE_HZ = 100.0
KINECT_RATE_HZ = 30.0


def parse_paired_spec(text: str) -> tuple[Path, str] | None:
    """``FILE.npz:KEY`` -> (path, key); None when ``text`` is not of that form."""
    path, sep, key = str(text).rpartition(":")
    if not sep or not path.lower().endswith(".npz") or not key:
        return None
    return Path(path), key


def read_paired(path: str | Path, key: str) -> tuple[Motion, np.ndarray]:
    """The repetition's Kinect motion and its optical reference ``(T, 22, 3)`` (NaN: no reference)."""
    path = Path(path)
    with np.load(path) as z:
        missing = [f"{p}_{key}" for p in ("kinect", "vicon", "fs", "off", "R", "t") if f"{p}_{key}" not in z]
        if missing:
            raise ValueError(f"{path.name}: no repetition {key!r} (missing arrays {', '.join(missing)}); "
                             f"keys look like cor_m07_s02_e01")
        kinect = z[f"kinect_{key}"].astype(np.float64)
        vicon = z[f"vicon_{key}"].astype(np.float64) * float(z["vicon_unit_m"])
        fs, off = float(z[f"fs_{key}"]), float(z[f"off_{key}"])
        R, t = z[f"R_{key}"].astype(np.float64), z[f"t_{key}"].astype(np.float64)
    if kinect.ndim != 3 or kinect.shape[1:] != (len(JOINTS), 3):
        raise ValueError(f"{path.name}:{key}: Kinect array is {kinect.shape}, expected (T, {len(JOINTS)}, 3)")
    vicon[(vicon == 0).all(axis=2)] = np.nan  # a lost marker is stored as the origin
    idx = {m: i for i, m in enumerate(MARKERS)}
    joints = [JOINTS.index(j) for j in REFERENCE]
    ref_v = np.stack([vicon[:, [idx[m] for m in REFERENCE[j]]].mean(axis=1) for j in REFERENCE], axis=1)
    t_kinect = np.arange(kinect.shape[0]) / fs + off
    t_vicon = np.arange(vicon.shape[0]) / VICON_RATE_HZ
    from scipy.interpolate import interp1d

    sampled = interp1d(t_vicon, ref_v, axis=0, bounds_error=False, fill_value=np.nan)(t_kinect)
    reference = np.full(kinect.shape, np.nan)
    reference[:, joints] = (sampled - t) @ R  # R^T (v - t), row-vector form
    conf = np.isfinite(kinect).all(axis=2).astype(np.float64)
    motion = Motion(kinect, conf, np.arange(kinect.shape[0]) / KINECT_RATE_HZ, KINECT_RATE_HZ, SKELETON,
                    meta={"source": f"{path.name}:{key}"})
    return motion, reference
