"""C3D marker files through ``ezc3d``.

:func:`read_c3d` returns the 3-D markers as a :class:`~streamfix.motion.Motion`:

* units from ``POINT:UNITS`` (``mm`` -> x0.001, ``cm`` -> x0.01, ``m`` -> x1; ``mm`` when
  absent, the C3D default);
* a sample is **missing** (NaN, confidence 0) when it is stored as NaN, as exactly
  ``0, 0, 0`` (how many exporters, e.g. 03_rolling.c3d, store gaps) or with a negative
  residual (the C3D standard's "invalid point");
* timestamps ``(first_frame + i) / rate`` seconds;
* the skeleton is a marker set: joint names are the marker labels (made unique), and
  it has **no bones** (markers are not joints; rigid pairs can be estimated from the
  data). It is named ``c3d:<M>m-<hash of labels>`` and registered.

:func:`write_c3d` writes positions in millimetres with missing samples as
``0, 0, 0`` and residual -1 (the C3D convention), so any C3D reader sees them as
invalid, and :func:`read_c3d` reads them back as missing. The first timestamp is kept
as the header's first frame (timestamps are assumed uniform at ``rate_hz``).
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..motion import Motion
from ..skeletons import Skeleton, register_skeleton
from .errors import MotionFileError

__all__ = ["read_c3d", "write_c3d", "marker_skeleton"]

_UNITS = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "dm": 0.1}


def marker_skeleton(labels: list[str]) -> Skeleton:
    """A bone-less marker-set skeleton named ``c3d:<M>m-<hash>``; labels made unique."""
    names: list[str] = []
    seen: set[str] = set()
    for i, lab in enumerate(labels):
        base = str(lab).strip() or f"M{i:03d}"
        name, k = base, 2
        while name in seen:
            name, k = f"{base}#{k}", k + 1
        seen.add(name)
        names.append(name)
    digest = hashlib.sha1("\n".join(names).encode()).hexdigest()[:8]
    return Skeleton(f"c3d:{len(names)}m-{digest}", tuple(names), ())


def _frames_in_file(path: Path) -> tuple[int, int] | None:
    """(frames the C3D header declares, whole frames the file holds), from the raw header.

    ezc3d silently shortens a truncated file's frame count, so truncation is detected
    from the 512-byte header (C3D spec: word 2 points, 3 analog samples per frame,
    4/5 first/last frame, 7-8 scale factor, 9 data start block) and the file size.
    """
    raw = path.read_bytes()[:512]
    if len(raw) < 20 or raw[1] != 0x50:
        return None
    param_block = raw[0]
    with path.open("rb") as f:
        f.seek((param_block - 1) * 512 + 3)
        proc = f.read(1)
    order = ">" if proc and proc[0] == 86 else "<"  # 84 Intel, 85 DEC, 86 MIPS (big-endian)
    n_points, n_analog, first, last = np.frombuffer(raw[2:10], dtype=order + "u2").astype(int)
    # only the sign of the scale factor matters (negative = float data); where the sign bit sits:
    sign_byte = {84: 15, 85: 13, 86: 12}.get(proc[0] if proc else 84, 15)
    scale = -1.0 if raw[sign_byte] & 0x80 else 1.0
    data_start = int(np.frombuffer(raw[16:18], dtype=order + "u2")[0])
    word = 4 if scale < 0 else 2
    frame_bytes = (4 * n_points + n_analog) * word
    declared = last - first + 1
    if frame_bytes <= 0 or declared <= 0 or data_start < 2:
        return None
    available = path.stat().st_size - (data_start - 1) * 512
    return declared, max(available, 0) // frame_bytes


def _param(c, group: str, name: str, default=None):
    try:
        return c["parameters"][group][name]["value"]
    except KeyError:
        return default


def read_c3d(path: str | Path) -> Motion:
    """Read the 3-D markers of a C3D file (metres, seconds, marker-set skeleton)."""
    import ezc3d

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        c = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises OSError/RuntimeError with its own text
        raise MotionFileError(path, f"not a readable C3D file ({exc})") from None
    pts = np.asarray(c["data"]["points"], dtype=np.float64)  # (4, M, T)
    hdr = c["header"]["points"]
    n_markers, n_frames = pts.shape[1], pts.shape[2]
    sizes = _frames_in_file(path)
    if sizes is not None and sizes[1] < sizes[0]:
        raise MotionFileError(
            path,
            f"truncated: the header declares {sizes[0]} frames, the file's data stops after {sizes[1]}",
            frame=sizes[1],
        )
    rate_v = _param(c, "POINT", "RATE")
    rate = float(rate_v[0]) if rate_v is not None and len(rate_v) else float(hdr["frame_rate"])
    if not (np.isfinite(rate) and rate > 0):
        raise MotionFileError(path, f"POINT:RATE must be a positive frame rate, got {rate}")
    labels = list(_param(c, "POINT", "LABELS", []) or [])
    if len(labels) < n_markers:
        labels += [""] * (n_markers - len(labels))
    labels = labels[:n_markers]
    units_v = _param(c, "POINT", "UNITS")
    units = (str(units_v[0]).strip().lower() if units_v is not None and len(units_v) else "") or "mm"
    if units not in _UNITS:
        raise MotionFileError(path, f"POINT:UNITS {units!r} is not one of {', '.join(_UNITS)}")
    xyz = pts[:3].transpose(2, 1, 0) * _UNITS[units]  # (T, M, 3)
    missing = ~np.isfinite(xyz).all(axis=2) | (pts[:3] == 0).all(axis=0).T
    res = c["data"].get("meta_points", {}).get("residuals")
    if res is not None and np.shape(res)[1:] == (n_markers, n_frames):
        missing |= np.asarray(res)[0].T < 0
    xyz[missing] = np.nan
    conf = (~missing).astype(np.float64)
    skeleton = register_skeleton(marker_skeleton(labels))
    first = int(hdr["first_frame"])
    meta = {"source": str(path), "format": "c3d", "units": units, "labels": labels, "first_frame": first}
    return Motion(xyz, conf, (first + np.arange(n_frames)) / rate, rate, skeleton, meta=meta)


def write_c3d(motion: Motion, path: str | Path) -> None:
    """Write the motion's joints/markers as C3D points (mm, missing = 0,0,0 with residual -1)."""
    import ezc3d

    T, M = motion.n_frames, motion.n_joints
    observed = motion.observed & np.isfinite(motion.positions).all(axis=2)
    pts = np.zeros((4, M, T))
    mm = np.where(observed[:, :, None], motion.positions * 1000.0, 0.0)
    pts[:3] = mm.transpose(2, 1, 0)
    pts[3] = 1.0
    res = np.where(observed, 0.0, -1.0).T[None]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(motion.rate_hz)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(motion.skeleton.joint_names)
    c.add_parameter("POINT", "UNITS", "mm")
    first = int(round(motion.timestamps[0] * motion.rate_hz)) if T else 0
    if 0 <= first < 65535:  # keeps the time origin: timestamps are (first_frame + i) / rate
        c["header"]["points"]["first_frame"] = first
    c["data"]["points"] = pts
    c["data"]["meta_points"] = {"residuals": res, "camera_masks": np.zeros((7, M, T), dtype=bool)}
    c.write(str(path))
    if not Path(path).is_file():  # ezc3d returns quietly when it cannot open the file
        raise OSError(f"{path}: the C3D file could not be written (missing or unwritable directory?)")
