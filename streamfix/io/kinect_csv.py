"""Kinect v2 body-tracking CSV (the LabanotationSuite layout).

One line per frame, comma separated, optional trailing comma::

    timestamp, then 25 x (x, y, z, trackingState)

* ``timestamp`` is in 100 ns ticks (Windows ``TimeSpan`` / Kinect ``RelativeTime``);
  :class:`~streamfix.motion.Motion` timestamps are seconds (ticks * 1e-7).
* ``x, y, z`` are Kinect camera-space metres.
* ``trackingState``: 2 tracked -> confidence 1.0, 1 inferred -> 0.5
  (``CONFIDENCE_INFERRED``), 0 not tracked -> missing (NaN, confidence 0).

The frame rate is estimated from the timestamps as 1 / median(dt) (robust to the
dropped frames that show as 2x gaps); a one-frame file falls back to the Kinect v2's
nominal 30 Hz. The writer writes the same layout (missing joints as ``0,0,0,0``), so
``read_kinect_csv(write_kinect_csv(m))`` reproduces ``m`` within print precision.
Blank lines, lines starting with ``#`` and a column-name header line (first field
starting with a letter, before any frame) are skipped.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..motion import CONFIDENCE_INFERRED, CONFIDENCE_TRACKED, Motion
from ..skeletons import KINECT_V2
from .errors import MotionFileError

__all__ = ["read_kinect_csv", "write_kinect_csv", "parse_kinect_csv_line", "KINECT_NOMINAL_HZ", "TICKS_PER_SECOND"]

KINECT_NOMINAL_HZ = 30.0
TICKS_PER_SECOND = 10_000_000  # 100 ns ticks
N_JOINTS = KINECT_V2.n_joints
N_FIELDS = 1 + 4 * N_JOINTS  # 101
_STATE_TO_CONF = np.array([0.0, CONFIDENCE_INFERRED, CONFIDENCE_TRACKED])


def _fields(line: str) -> list[str]:
    parts = line.strip().split(",")
    if parts and parts[-1].strip() == "":
        parts = parts[:-1]  # trailing comma
    return parts


def _locate_bad_value(path: str | Path, lineno: int, parts: list[str]) -> MotionFileError:
    for k, s in enumerate(parts):
        try:
            float(s)
        except ValueError:
            if k == 0:
                what = f"timestamp is not a number: {s.strip()!r}"
            else:
                j, c = divmod(k - 1, 4)
                what = (
                    f"joint {j} ({KINECT_V2.joint_names[j]}) {'xyz'[c] if c < 3 else 'trackingState'} "
                    f"is not a number: {s.strip()!r}"
                )
            return MotionFileError(path, what, line=lineno)
    return MotionFileError(path, "unparseable line", line=lineno)


def parse_kinect_csv_line(line: str, *, path: str | Path = "<stdin>", lineno: int = 1) -> tuple[int, np.ndarray, np.ndarray]:
    """One CSV line -> ``(ticks, positions (25,3) m with NaN for missing, confidence (25,))``.

    For streaming sources (``serve --source stdin``). Raises :class:`MotionFileError`.
    """
    ticks, pos, conf, _ = _parse_rows(path, [(lineno, _fields(line))])
    return int(ticks[0]), pos[0], conf[0]


def _parse_rows(path: str | Path, rows: list[tuple[int, list[str]]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(ticks, positions, confidence, joint-samples whose state said seen but whose coordinate
    was NaN/inf, read as missing)``; raises :class:`MotionFileError` naming a malformed line."""
    for lineno, parts in rows:
        if len(parts) != N_FIELDS:
            raise MotionFileError(
                path,
                f"expected {N_FIELDS} fields (timestamp + {N_JOINTS} x 4), got {len(parts)}",
                line=lineno,
            )
    # timestamps parsed as integers (ticks exceed float32 but not int64)
    ticks = np.empty(len(rows), dtype=np.int64)
    for i, (lineno, parts) in enumerate(rows):
        s = parts[0].strip()
        try:
            ticks[i] = int(s)
        except ValueError:
            try:
                ticks[i] = int(round(float(s)))
            except ValueError:
                raise _locate_bad_value(path, lineno, parts) from None
    try:
        values = np.array([parts[1:] for _, parts in rows], dtype=np.float64) if rows else np.zeros((0, N_FIELDS - 1))
    except ValueError:
        for lineno, parts in rows:
            try:
                np.array(parts[1:], dtype=np.float64)
            except ValueError:
                raise _locate_bad_value(path, lineno, parts) from None
        raise
    values = values.reshape(len(rows), N_JOINTS, 4)
    state = values[:, :, 3]
    bad = ~np.isin(state, (0.0, 1.0, 2.0))
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise MotionFileError(
            path,
            f"joint {j} ({KINECT_V2.joint_names[j]}) trackingState must be 0, 1 or 2, got {state[i, j]:g}",
            line=rows[i][0],
        )
    conf = _STATE_TO_CONF[state.astype(np.intp)]
    pos = values[:, :, :3].copy()
    # a joint with a NaN/inf coordinate is missing whatever its trackingState says: the
    # frame's other joints are good data
    nonfinite = ~np.isfinite(pos).all(axis=2) & (conf > 0)
    conf[nonfinite] = 0.0
    pos[conf <= 0] = np.nan
    return ticks, pos, conf, int(nonfinite.sum())


def read_kinect_csv(path: str | Path) -> Motion:
    """Read a Kinect v2 CSV into a :class:`Motion` (metres, seconds, ``KINECT_V2``)."""
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError as exc:
        raise MotionFileError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    rows = []
    headers = 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if not rows and s[0].isalpha():
            headers += 1
            continue  # a column-name header line (e.g. "Timestamp,SpineBase_X,...")
        rows.append((lineno, _fields(s)))
    if not rows:
        if headers:
            raise MotionFileError(path, f"no frames: {headers} line(s) of text but no frame line "
                                        f"(timestamp + {N_JOINTS} x (x, y, z, trackingState))")
        raise MotionFileError(path, "no frames (empty file)")
    ticks, pos, conf, nonfinite = _parse_rows(path, rows)
    dticks = np.diff(ticks)
    if (dticks <= 0).any():
        i = int(np.argmax(dticks <= 0))
        raise MotionFileError(
            path,
            f"timestamp {ticks[i + 1]} is not after the previous frame's {ticks[i]} (timestamps must increase)",
            line=rows[i + 1][0],
        )
    if len(dticks):
        rate = TICKS_PER_SECOND / float(np.median(dticks))
    else:
        rate = KINECT_NOMINAL_HZ
    timestamps = ticks.astype(np.float64) / TICKS_PER_SECOND
    meta = {"source": str(path), "format": "kinect_v2_csv"}
    if nonfinite:
        meta["nonfinite_joints"] = nonfinite  # tracked or inferred, but a NaN/inf coordinate: read as missing
    return Motion(pos, conf, timestamps, rate, KINECT_V2, meta=meta)


def _state_from_confidence(motion: Motion) -> np.ndarray:
    conf = motion.confidence
    observed = (conf > 0) & np.isfinite(motion.positions).all(axis=2)
    state = np.where(conf > 0.75, 2, 1)  # 1.0 -> tracked; (0, 0.75] -> inferred
    return np.where(observed, state, 0)


def write_kinect_csv(motion: Motion, path: str | Path, *, decimals: int | None = None) -> None:
    """Write a ``KINECT_V2`` motion in the layout :func:`read_kinect_csv` reads.

    Confidence > 0.75 is written as tracked (2), other observed samples as inferred
    (1), missing samples as ``0,0,0,0``. Timestamps are written as 100 ns ticks.
    Coordinates are written with 9 significant digits, or with ``decimals`` fixed
    decimals (4 = 0.1 mm, far below sensor noise, for compact files).
    """
    if motion.skeleton.joint_names != KINECT_V2.joint_names:
        raise ValueError(
            f"Kinect v2 CSV needs the {N_JOINTS}-joint kinect_v2 skeleton, got "
            f"{motion.skeleton.name!r} with {motion.n_joints} joints (retarget first: "
            "streamfix.io.retarget.bvh_to_kinect_v2)"
        )
    ticks = np.round(motion.timestamps * TICKS_PER_SECOND).astype(np.int64)
    if len(ticks) > 1 and (np.diff(ticks) <= 0).any():
        raise ValueError("timestamps must increase by at least 100 ns per frame to be written as ticks")
    state = _state_from_confidence(motion)
    pos = np.where(state[:, :, None] > 0, motion.positions, 0.0)
    T = motion.n_frames
    block = np.concatenate([pos, state[:, :, None].astype(np.float64)], axis=2).reshape(T, 4 * N_JOINTS)
    c = "%.9g" if decimals is None else f"%.{int(decimals)}f"
    fmt = ",".join([c, c, c, "%d"] * N_JOINTS)
    lines = [f"{int(t)}," + (fmt % tuple(row)) + ",\n" for t, row in zip(ticks, block)]
    Path(path).write_text("".join(lines))
