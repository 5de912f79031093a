"""TRC files: OpenSim's marker trajectories (tab-separated text), written and read.

Layout (OpenSim's ``.trc``; one marker per joint, any skeleton)::

    PathFileType  4  (X/Y/Z)  <file name>
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    <rate>    <rate>      <T>        <J>         mm     <rate>        1                   <T>
    Frame#  Time  <joint 1>  <tab> <tab>  <joint 2> ...
                  X1  Y1  Z1  X2  Y2  Z2 ...
    <blank line>
    1  0.000000  x y z  x y z ...

Frames are numbered from 1; Time is seconds from the motion's first timestamp; a missing
joint leaves its three fields empty (OpenSim reads them as missing markers).
Coordinates are written in the motion's own frame (streamfix's sensor layouts and BVH
are y up, as OpenSim expects), in ``units`` ``"mm"`` (OpenSim's usual) or ``"m"``.

:func:`read_trc` accepts mm, cm and m, returns metres, and names the skeleton after a
registered layout when the marker names match one (so a Kinect v2 TRC keeps its bones),
else a bone-less marker skeleton ``trc:<J>m-<hash>``.
"""
from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np

from ..motion import Motion
from ..skeletons import Skeleton, get_skeleton, register_skeleton, skeleton_names
from .errors import MotionFileError

__all__ = ["write_trc", "read_trc", "TRC_UNITS"]

TRC_UNITS = {"mm": 1000.0, "cm": 100.0, "m": 1.0}  # file units per metre
_PLAIN_DECIMAL = re.compile(r"[-+]?\d+(\.\d*)?")  # 12, -3.25: a value whose decimals can be counted


def write_trc(motion: Motion, path: str | Path, units: str = "mm") -> None:
    """Write ``motion`` as an OpenSim TRC file in ``units`` (``"mm"`` or ``"m"``)."""
    if units not in ("mm", "m"):
        raise ValueError(f"TRC units must be 'mm' or 'm', got {units!r}")
    path = Path(path)
    names = motion.skeleton.joint_names
    rate = f"{motion.rate_hz:.10g}"
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate}\t{rate}\t{motion.n_frames}\t{len(names)}\t{units}\t{rate}\t1\t{motion.n_frames}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"{a}{k}" for k in range(1, len(names) + 1) for a in "XYZ"),
        "",
    ]
    values = motion.positions.reshape(motion.n_frames, -1) * TRC_UNITS[units]
    text = np.char.mod("%.6f", values)
    text[~np.isfinite(values)] = ""
    times = np.char.mod("%.6f", motion.timestamps - (motion.timestamps[0] if motion.n_frames else 0.0))
    frames = np.char.mod("%d", np.arange(1, motion.n_frames + 1))
    rows = np.column_stack([frames, times, text]) if motion.n_frames else np.zeros((0, 2), str)
    body = ["\t".join(r) for r in rows.tolist()]
    path.write_text("\n".join(header + body) + "\n")


def _skeleton_for(names: tuple[str, ...]) -> Skeleton:
    """A registered layout with these joint names: one with bones first, a built-in before a file's (``c3d:...``)."""
    matches = [get_skeleton(k) for k in skeleton_names() if get_skeleton(k).joint_names == names]
    matches.sort(key=lambda s: (s.n_bones == 0, ":" in s.name, s.name))
    if matches:
        return matches[0]
    digest = hashlib.sha1("\n".join(names).encode()).hexdigest()[:8]
    return register_skeleton(Skeleton(f"trc:{len(names)}m-{digest}", names, ()))


def _torn_last_row(fields: list[str], prev_fields: list[str] | None, n_markers: int) -> str | None:
    """Why the last row of a file with no final newline was cut mid-write, or None if it is whole.

    Why: a copy or a write stopped inside a number still leaves the header's field count
    when it stops in the last marker's Z, so the count alone does not show it. A row is
    torn when it has fewer fields than the row before it (a writer's trailing tab is gone),
    when its last marker has some but not all of X/Y/Z (a writer writes all three or none),
    or when its last value has fewer decimals than every other value of the row, all
    written with the same number (streamfix and most exporters write fixed decimals).
    """
    if n_markers < 1:
        return None
    if prev_fields is not None and len(fields) < len(prev_fields):
        return f"it has {len(fields)} fields, the row before it {len(prev_fields)}"
    last = [f.strip() for f in fields[2 + 3 * (n_markers - 1):2 + 3 * n_markers]]
    if any(last) and not all(last):
        return f"its last marker has only {sum(map(bool, last))} of X/Y/Z"
    values = [f.strip() for f in fields[2:2 + 3 * n_markers]]
    if not _PLAIN_DECIMAL.fullmatch(values[-1]):
        return None  # empty (a missing marker), nan, exponent: nothing to compare
    decimals = {len(f.partition(".")[2]) for f in values[:-1] if _PLAIN_DECIMAL.fullmatch(f)}
    ours = len(values[-1].partition(".")[2])
    if len(decimals) == 1 and ours < (d := decimals.pop()):
        return f"its last value {values[-1]!r} has {ours} decimal(s), the row's other values {d}"
    return None


def read_trc(path: str | Path) -> Motion:
    """Read an OpenSim TRC file: marker positions in metres (see module doc).

    A truncated file is refused, as the other readers refuse one (naming the file and the
    line): a row with fewer fields than ``2 + 3 * NumMarkers``, a last row cut inside a
    value (no final newline, see :func:`_torn_last_row`), or fewer rows than the header's
    ``NumFrames``. Why: read on, a torn row becomes a frame with joints missing and a
    half-written number a wrong coordinate, and the cleaned output hides both.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError as exc:
        raise MotionFileError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    lines = text.splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise MotionFileError(path, "not a TRC file: the first line must start with 'PathFileType'", line=1)
    keys = lines[1].split("\t")
    vals = lines[2].split("\t")
    header = dict(zip((k.strip() for k in keys), (v.strip() for v in vals)))
    for key in ("DataRate", "NumMarkers", "Units"):
        if key not in header:
            raise MotionFileError(path, f"TRC header has no {key} (line 2 names the fields, line 3 their values)", line=2)
    try:
        rate = float(header["DataRate"])
        n_markers = int(header["NumMarkers"])
    except ValueError:
        raise MotionFileError(path, f"DataRate/NumMarkers are not numbers: {header['DataRate']!r}, "
                                    f"{header['NumMarkers']!r}", line=3) from None
    declared = header.get("NumFrames")
    if declared is not None:
        try:
            declared = int(declared)
        except ValueError:
            raise MotionFileError(path, f"NumFrames is not an integer: {declared!r}", line=3) from None
    units = header["Units"].lower()
    if units not in TRC_UNITS:
        raise MotionFileError(path, f"unknown TRC units {header['Units']!r}; expected one of {', '.join(TRC_UNITS)}", line=3)
    names = tuple(n.strip() for n in lines[3].split("\t")[2:] if n.strip())
    if len(names) != n_markers:
        raise MotionFileError(path, f"NumMarkers says {n_markers}, the marker line names {len(names)}", line=4)
    n_fields = 2 + 3 * n_markers
    data = [i for i in range(5, len(lines)) if lines[i].strip()]
    ends_inside_last = not text.endswith(("\n", "\r"))  # no newline after the last row
    rows, times, row_lines = [], [], []
    prev = None
    for i in data:
        fields = lines[i].split("\t")
        torn = ends_inside_last and i == data[-1]
        if len(fields) < n_fields:
            what = (f"expected {n_fields} fields (Frame#, Time and X/Y/Z of {n_markers} markers), "
                    f"got {len(fields)}")
            raise MotionFileError(path, f"truncated: the file ends inside this row: {what}" if torn else what,
                                  line=i + 1)
        why = _torn_last_row(fields, prev, n_markers) if torn else None
        if why:
            raise MotionFileError(path, f"truncated: the file ends inside this row: no newline after it, and {why}",
                                  line=i + 1)
        try:
            times.append(float(fields[1]))
            rows.append([float(f) if f.strip() else np.nan for f in fields[2:n_fields]])
        except ValueError as exc:
            raise MotionFileError(path, f"expected numbers: {exc}", line=i + 1) from None
        row_lines.append(i + 1)
        prev = fields
    if not rows:
        raise MotionFileError(path, "no frames after the header", line=len(lines))
    if declared is not None and len(rows) < declared:
        raise MotionFileError(path, f"truncated: the header declares NumFrames {declared}, "
                                    f"{len(rows)} frame rows found", line=len(lines))
    if not (np.isfinite(rate) and rate > 0):
        raise MotionFileError(path, f"DataRate must be positive Hz, got {rate}", line=3)
    positions = np.array(rows).reshape(len(rows), n_markers, 3) / TRC_UNITS[units]
    t = np.array(times)
    if np.any(np.diff(t) <= 0):
        bad = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise MotionFileError(path, f"Time must increase; frame {bad + 1} repeats or goes back", line=row_lines[bad])
    confidence = np.isfinite(positions).all(axis=2).astype(np.float64)
    meta = {"source": str(path), "format": "trc", "units": units}
    return Motion(positions, confidence, t, rate, _skeleton_for(names), meta=meta)
