"""Paired recordings: a sensor's skeleton and optical motion capture of the same movement.

The only data where a consumer sensor's skeleton has a ground truth (see
``../shared/data/paired/README.md``). Each loader returns a :class:`PairedTake`: the
sensor skeleton as a :class:`~streamfix.motion.Motion` (its own skeleton, its own
frame times) and the **reference** joint positions ``(T, J, 3)`` in metres in the
*sensor's* coordinate frame at the *sensor's* frame times, NaN where a joint has no
reference (the markers do not define it) or a marker was lost. The sensor estimates
joint centres while markers sit on the skin, so expect a roughly constant offset per
joint of a few centimetres; the evaluation removes it ("debiased" error).

UI-PRMD (Kinect v1 + Vicon 100 Hz, ``uiprmd/uiprmd_*.npz`` + ``pairs.csv``)
    Alignment is given per repetition: Kinect frame ``i`` is at Vicon time
    ``i / fs + off`` s and ``R k + t`` maps Kinect coordinates into the Vicon frame, so
    a Vicon point ``v`` is ``R^T (v - t)`` in the Kinect frame. The Kinect stream has
    no timestamps: its frame ``i`` is at ``i / fs`` s and the motion's rate is ``fs``.
    A reference joint is the mean of its markers (:data:`UIPRMD_REFERENCE`), NaN when
    any of them is lost (stored as 0, 0, 0), sampled at the Kinect frame times by
    linear interpolation between the two neighbouring Vicon frames. The *trustworthy*
    subset is ``pos_corr > 0.95`` and ``25 <= fs_eff <= 33`` in ``pairs.csv``
    (a repetition missing from it is not trustworthy; one without an alignment in the
    archive is not listed at all).
KERAAL (Kinect v2 ~30 Hz + Vicon rigid targets ~60 Hz, two text files per take)
    Both start together; Kinect frame ``i`` is at ``i / 30`` s, Vicon frame ``j`` at
    ``j / 60`` s (the nominal rates fit best: other rates and start offsets were
    tried and gave larger residuals). A target sits on a segment, not at the joint,
    so the reference of joint ``j`` paired with target ``g`` (:data:`KERAAL_PAIRS`) is
    ``A (R_g(t) o_j + p_g(t)) + b``: the offset ``o_j`` in the target's own frame and
    one rigid transform ``A, b`` (Vicon -> Kinect) are fitted by least squares with
    outlier rejection (:func:`streamfix.core.rigid.fit_rigid_with_offsets`), so the
    sensor's gross failures do not pull the alignment but are still scored.
    Quaternions are stored ``x y z w``. Every KERAAL take counts as trustworthy.
"""
from __future__ import annotations

import csv
import functools
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.resample import resample_values
from ..core.rigid import fit_rigid_with_offsets
from ..motion import Motion
from ..skeletons import KINECT_V1_UIPRMD, KINECT_V2
from .errors import MotionFileError

__all__ = [
    "PairedTake",
    "TakeRef",
    "find_takes",
    "load_take",
    "load_uiprmd_take",
    "load_keraal_take",
    "default_paired_dir",
    "UIPRMD_MARKERS",
    "UIPRMD_REFERENCE",
    "KERAAL_TARGETS",
    "KERAAL_PAIRS",
    "SUBSETS",
]

SUBSETS = ("trustworthy", "all")

UIPRMD_VICON_HZ = 100.0
UIPRMD_MARKERS = tuple(
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA RELB "
    "RFRM RWRA RWRB RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE".split()
)
# Kinect v1 joint -> the Plug-in-Gait markers whose mean is its reference (README of uiprmd/)
UIPRMD_REFERENCE: dict[str, tuple[str, ...]] = {
    "HeadTip": ("LFHD", "RFHD", "LBHD", "RBHD"),
    "Neck": ("C7", "CLAV"),
    "LShoulder": ("LSHO",), "RShoulder": ("RSHO",),
    "LElbow": ("LELB",), "RElbow": ("RELB",),
    "LWrist": ("LWRA", "LWRB"), "RWrist": ("RWRA", "RWRB"),
    "Waist": ("LASI", "RASI", "LPSI", "RPSI"),
    "LHip": ("LASI", "LPSI"), "RHip": ("RASI", "RPSI"),
    "LKnee": ("LKNE",), "RKnee": ("RKNE",),
    "LAnkle": ("LANK",), "RAnkle": ("RANK",),
    "LFoot": ("LTOE",), "RFoot": ("RTOE",),
}
UIPRMD_MIN_POS_CORR = 0.95
UIPRMD_FS_BAND_HZ = (25.0, 33.0)

KERAAL_KINECT_HZ = 30.0
KERAAL_VICON_HZ = 60.0
KERAAL_TARGETS = (
    "RForearm", "LForearm", "RArm", "LArm", "Chest", "RThigh", "LThigh", "RShoulder", "LShoulder",
    "RHand", "LHand", "RFoot", "LFoot", "Hips", "Head", "RTibia", "LTibia",
)
# (Kinect v2 joint, Vicon target it rides on): the pairs the README lists as working
KERAAL_PAIRS: tuple[tuple[str, str], ...] = (
    ("HandRight", "RHand"), ("HandLeft", "LHand"), ("WristRight", "RHand"), ("WristLeft", "LHand"),
    ("Head", "Head"), ("SpineBase", "Hips"), ("ElbowRight", "RForearm"), ("ElbowLeft", "LForearm"),
    ("AnkleRight", "RFoot"), ("AnkleLeft", "LFoot"), ("SpineShoulder", "Chest"),
)


@dataclass
class PairedTake:
    """One repetition/take: the sensor's motion and the reference in its frame.

    ``reference`` ``(T, J, 3)`` metres, the sensor's coordinate frame and frame times;
    NaN where the joint has no reference or a marker was lost. ``meta`` holds the
    alignment (and, for KERAAL, the fit's residuals).
    """

    dataset: str
    key: str
    subject: str
    movement: str
    trustworthy: bool
    sensor: Motion
    reference: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        want = self.sensor.positions.shape
        if self.reference.shape != want:
            raise ValueError(f"{self.dataset} {self.key}: reference must be {want}, got {self.reference.shape}")

    @property
    def referenced(self) -> np.ndarray:
        """``(J,)`` bool: joints with a reference in at least one frame."""
        return np.isfinite(self.reference).all(axis=2).any(axis=0)


@dataclass(frozen=True)
class TakeRef:
    """Where a take lives: dataset, source file and key (picklable, for worker processes)."""

    dataset: str
    source: str
    key: str


def default_paired_dir() -> Path:
    """``../shared/data/paired`` beside the repository (or beside the working directory)."""
    candidates = [Path(__file__).resolve().parents[2].parent / "shared" / "data" / "paired",
                  Path.cwd().resolve().parent / "shared" / "data" / "paired"]
    for c in candidates:
        if c.is_dir():
            return c
    raise FileNotFoundError(
        "paired recordings not found; tried " + ", ".join(str(c) for c in candidates) + " (pass the directory)"
    )


def _sample_at(values: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``values`` (axis 0 = frames) at fractional frames ``u`` by linear interpolation;
    NaN outside ``[0, len - 1]`` or next to a NaN sample."""
    n = values.shape[0]
    a = np.clip(np.floor(u).astype(np.intp), 0, n - 1)
    out = resample_values(values, a, np.minimum(a + 1, n - 1), np.clip(u - a, 0.0, 1.0))
    out[(u < 0) | (u > n - 1)] = np.nan
    return out


# ----------------------------------------------------------------------------- UI-PRMD
def _npz(path: str):
    """The open archive (lazy: arrays are read on access). One per process: a forked
    worker must not share the parent's file offset."""
    return _npz_in_process(path, os.getpid())


@functools.lru_cache(maxsize=8)
def _npz_in_process(path: str, pid: int):
    return np.load(path)


@functools.lru_cache(maxsize=8)
def _pairs_table(directory: str) -> dict[str, dict[str, str]]:
    path = Path(directory) / "pairs.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    need = {"key", "pos_corr", "fs_eff"}
    if rows and not need <= set(rows[0]):
        raise MotionFileError(path, f"expected columns {sorted(need)}, got {sorted(rows[0])}", line=1)
    return {r["key"]: r for r in rows}


def _uiprmd_trustworthy(row: dict[str, str] | None) -> bool:
    if row is None:
        return False
    lo, hi = UIPRMD_FS_BAND_HZ
    return float(row["pos_corr"]) > UIPRMD_MIN_POS_CORR and lo <= float(row["fs_eff"]) <= hi


def _uiprmd_keys(npz_path: Path) -> list[str]:
    """Repetitions with a Kinect stream and an alignment (one in the release has none)."""
    files = set(_npz(str(npz_path)).files)
    return sorted(k[len("kinect_"):] for k in files if k.startswith("kinect_") and f"fs_{k[len('kinect_'):]}" in files)


def load_uiprmd_take(npz_path: str | Path, key: str) -> PairedTake:
    """One UI-PRMD repetition (``key`` e.g. ``cor_m07_s02_e01``) with its Vicon reference."""
    npz_path = Path(npz_path)
    z = _npz(str(npz_path))
    names = [f"{p}_{key}" for p in ("kinect", "vicon", "fs", "off", "R", "t")]
    missing = [n for n in names + ["vicon_unit_m"] if n not in z.files]
    if missing:
        raise MotionFileError(npz_path, f"repetition {key!r}: expected arrays {', '.join(missing)}, not present")
    kin = np.asarray(z[names[0]], dtype=np.float64)
    vic_raw = np.asarray(z[names[1]])
    fs, off = float(z[names[2]]), float(z[names[3]])
    R = np.asarray(z[names[4]], dtype=np.float64)
    t = np.asarray(z[names[5]], dtype=np.float64)
    J = KINECT_V1_UIPRMD.n_joints
    if kin.ndim != 3 or kin.shape[1:] != (J, 3):
        raise MotionFileError(npz_path, f"{names[0]}: expected (T, {J}, 3), got {kin.shape}")
    if vic_raw.ndim != 3 or vic_raw.shape[1:] != (len(UIPRMD_MARKERS), 3):
        raise MotionFileError(npz_path, f"{names[1]}: expected (T, {len(UIPRMD_MARKERS)}, 3), got {vic_raw.shape}")
    if R.shape != (3, 3) or t.shape != (3,) or not fs > 0:
        raise MotionFileError(npz_path, f"{key}: expected R (3, 3), t (3,), fs > 0; got {R.shape}, {t.shape}, {fs}")
    # Vicon markers in metres, lost = (0, 0, 0) -> NaN, then into the Kinect frame: R^T (v - t)
    vic = vic_raw.astype(np.float64) * float(z["vicon_unit_m"])
    vic[(vic_raw == 0).all(axis=2)] = np.nan
    vic = (vic - t) @ R
    marker = {n: i for i, n in enumerate(UIPRMD_MARKERS)}
    ref_v = np.full((vic.shape[0], J, 3), np.nan)
    for joint, markers in UIPRMD_REFERENCE.items():
        ref_v[:, KINECT_V1_UIPRMD.index(joint)] = vic[:, [marker[m] for m in markers]].mean(axis=1)
    # sample at the Kinect frame times: Vicon frame u = (i / fs + off) * 100
    reference = _sample_at(ref_v, (np.arange(kin.shape[0]) / fs + off) * UIPRMD_VICON_HZ)
    motion = Motion.from_positions(kin, KINECT_V1_UIPRMD, fs)
    row = _pairs_table(str(npz_path.parent)).get(key)
    parts = key.split("_")  # <set>_mMM_sSS_eEE
    motion.meta.update(source=str(npz_path), key=key)
    return PairedTake(
        dataset="uiprmd",
        key=key,
        subject=parts[2] if len(parts) == 4 else "",
        movement=parts[1] if len(parts) == 4 else "",
        trustworthy=_uiprmd_trustworthy(row),
        sensor=motion,
        reference=reference,
        meta={"fs_hz": fs, "offset_s": off, "R": R, "t": t, "set": parts[0],
              "pos_corr": None if row is None else float(row["pos_corr"])},
    )


# ----------------------------------------------------------------------------- KERAAL
def _read_table(path: Path, n_items: int, what: str) -> np.ndarray:
    """Whitespace table of ``n_items`` x 7 numbers per line -> ``(T, n_items, 7)``."""
    rows = []
    with open(path) as fh:
        for line_no, line in enumerate(fh, 1):
            fields = line.split()
            if not fields:
                continue
            if len(fields) != 7 * n_items:
                raise MotionFileError(path, f"expected {7 * n_items} numbers ({n_items} {what} x 7), got {len(fields)}",
                                      line=line_no)
            try:
                rows.append([float(f) for f in fields])
            except ValueError as exc:
                raise MotionFileError(path, f"expected numbers: {exc}", line=line_no) from None
    if len(rows) < 4:
        raise MotionFileError(path, f"expected at least 4 frames, got {len(rows)}")
    return np.asarray(rows).reshape(len(rows), n_items, 7)


def _quat_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` stored x y z w (NaN if zero)."""
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(np.where(n > 0, q / np.where(n > 0, n, 1.0), np.nan), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _keraal_vicon_path(kinect_path: Path) -> Path:
    return kinect_path.with_name(kinect_path.name.replace("-Kinect-", "-Vicon-", 1))


def _keraal_key(kinect_path: Path) -> str:
    return kinect_path.stem.replace("-Kinect-", "-", 1)  # e.g. G3-CTK-P1T1-Unknown-C-0


def load_keraal_take(kinect_path: str | Path) -> PairedTake:
    """One KERAAL take from its ``*-Kinect-*.txt`` file (the ``*-Vicon-*.txt`` beside it)."""
    kinect_path = Path(kinect_path)
    vicon_path = _keraal_vicon_path(kinect_path)
    if vicon_path == kinect_path or not vicon_path.is_file():
        raise FileNotFoundError(f"{kinect_path}: expected its Vicon file {vicon_path.name} beside it")
    kin = _read_table(kinect_path, KINECT_V2.n_joints, "Kinect v2 joints")
    vic = _read_table(vicon_path, len(KERAAL_TARGETS), "Vicon targets")
    T = kin.shape[0]
    # Vicon at the Kinect frame times (both start together): frame u = i / 30 * 60
    u = np.arange(T) / KERAAL_KINECT_HZ * KERAAL_VICON_HZ
    pos_v = vic[:, :, :3] * 1e-3  # mm -> m
    pos_v[(vic[:, :, :3] == 0).all(axis=2)] = np.nan
    pos = _sample_at(pos_v, u)
    rot = _sample_at(_quat_xyzw_to_matrix(vic[:, :, 3:]), u)  # exact at Kinect frames (u integer)
    ji = [KINECT_V2.index(j) for j, _ in KERAAL_PAIRS]
    gi = [KERAAL_TARGETS.index(g) for _, g in KERAAL_PAIRS]
    sensor_xyz = kin[:, :, :3].copy()
    fit = fit_rigid_with_offsets(sensor_xyz[:, ji], rot[:, gi], pos[:, gi])
    reference = np.full(sensor_xyz.shape, np.nan)
    reference[:, ji] = fit.reference(rot[:, gi], pos[:, gi])
    motion = Motion.from_positions(sensor_xyz, KINECT_V2, KERAAL_KINECT_HZ)
    motion.meta.update(source=str(kinect_path))
    key = _keraal_key(kinect_path)
    parts = kinect_path.stem.split("-")  # G3 Kinect CTK P1T1 ...
    return PairedTake(
        dataset="keraal",
        key=key,
        subject=parts[3] if len(parts) > 3 else "",
        movement=parts[2] if len(parts) > 2 else "",
        trustworthy=True,
        sensor=motion,
        reference=reference,
        meta={"rotation": fit.rotation, "translation": fit.translation, "offsets": fit.offsets,
              "fit_residual_median_m": float(np.nanmedian(fit.residuals)),
              "fit_inlier_fraction": float(fit.inliers.sum() / np.isfinite(fit.residuals).sum()),
              "vicon_frames": int(vic.shape[0])},
    )


# ----------------------------------------------------------------------------- discovery
def _spread(items: list, limit: int | None) -> list:
    """At most ``limit`` items, evenly spaced over the list (so a quick run sees every movement)."""
    if limit is None or limit >= len(items):
        return items
    if limit < 1:
        raise ValueError(f"limit must be >= 1 repetition, got {limit}")
    return [items[i] for i in np.unique(np.linspace(0, len(items) - 1, limit).round().astype(int))]


def _uiprmd_refs(npz_files: list[Path], subset: str) -> list[TakeRef]:
    refs = []
    for f in npz_files:
        table = _pairs_table(str(f.parent))
        for key in _uiprmd_keys(f):
            if subset == "all" or _uiprmd_trustworthy(table.get(key)):
                refs.append(TakeRef("uiprmd", str(f), key))
    return refs


def _keraal_refs(files: list[Path]) -> list[TakeRef]:
    return [TakeRef("keraal", str(f), _keraal_key(f)) for f in files]


def find_takes(path: str | Path | None = None, subset: str = "trustworthy", limit: int | None = None) -> list[TakeRef]:
    """Takes under ``path``: the paired directory (``uiprmd/``, ``keraal/``), one of those
    directories, a ``uiprmd_*.npz`` or a KERAAL ``*-Kinect-*.txt`` file. None = the
    default directory. ``subset`` filters UI-PRMD; ``limit`` caps each dataset."""
    if subset not in SUBSETS:
        raise ValueError(f"unknown subset {subset!r}; expected one of: {', '.join(SUBSETS)}")
    path = default_paired_dir() if path is None else Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory (expected the paired recordings)")
    if path.is_file():
        if path.suffix == ".npz":
            return _spread(_uiprmd_refs([path], subset), limit)
        if "-Kinect-" in path.name and path.suffix == ".txt":
            return _keraal_refs([path])
        raise ValueError(f"{path}: expected a UI-PRMD .npz or a KERAAL *-Kinect-*.txt file")
    dirs = [d for d in (path / "uiprmd", path / "keraal") if d.is_dir()] or [path]
    refs: list[TakeRef] = []
    for d in dirs:
        refs += _spread(_uiprmd_refs(sorted(d.glob("uiprmd_*.npz")), subset), limit)
        refs += _spread(_keraal_refs(sorted(d.glob("*-Kinect-*.txt"))), limit)
    if not refs:
        raise ValueError(f"{path}: no paired takes found (expected uiprmd/uiprmd_*.npz or keraal/*-Kinect-*.txt"
                         f"{'' if subset == 'all' else ' in the ' + subset + ' subset'})")
    return refs


def load_take(ref: TakeRef) -> PairedTake:
    """Load the take a :class:`TakeRef` points at."""
    if ref.dataset == "uiprmd":
        return load_uiprmd_take(ref.source, ref.key)
    if ref.dataset == "keraal":
        return load_keraal_take(ref.source)
    raise ValueError(f"unknown paired dataset {ref.dataset!r}; expected uiprmd or keraal")
