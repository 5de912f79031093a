"""File formats: readers and writers for motions (Kinect v2 CSV, BVH, C3D, recordings).

``read_motion(path)`` / ``write_motion(motion, path)`` dispatch on the extension:

==========  =================================  ============================================
``.csv``    Kinect v2 body CSV                 :mod:`streamfix.io.kinect_csv`
``.bvh``    BVH (rotations <-> positions)      :mod:`streamfix.io.bvh`
``.c3d``    C3D markers (ezc3d)                :mod:`streamfix.io.c3d`
``.sfrec``  the project's recording format     :mod:`streamfix.io.recording`
``.trc``    OpenSim marker trajectories        :mod:`streamfix.io.trc`
``.json``   Azure Kinect body tracking export  :mod:`streamfix.io.azure_kinect` (read only)
==========  =================================  ============================================

Malformed files raise :class:`MotionFileError` (a ``ValueError``) naming the file,
line or frame, and what is wrong.
"""
from __future__ import annotations

import importlib
from pathlib import Path

from ..motion import Motion
from ..skeletons import Skeleton
from .errors import MotionFileError
from .resample import resample_motion

__all__ = [
    "read_motion",
    "write_motion",
    "resample_motion",
    "MotionFileError",
    "READ_FORMATS",
    "WRITE_FORMATS",
    "check_writable",
]

# extension -> (module, reader, writer or None)
_FORMATS = {
    ".csv": ("kinect_csv", "read_kinect_csv", "write_kinect_csv"),
    ".bvh": ("bvh", "read_bvh", "write_bvh"),
    ".c3d": ("c3d", "read_c3d", "write_c3d"),
    ".sfrec": ("recording", "read_recording", "write_recording"),
    ".trc": ("trc", "read_trc", "write_trc"),
    ".json": ("azure_kinect", "read_azure_kinect_json", None),
}
READ_FORMATS = tuple(_FORMATS)
WRITE_FORMATS = tuple(ext for ext, (_, _, w) in _FORMATS.items() if w)


def _handler(path: str | Path, which: int):
    if Path(path).is_dir():  # else named by its (missing) extension: "unknown extension '(none)'"
        supported = READ_FORMATS if which == 1 else WRITE_FORMATS
        raise ValueError(
            f"{Path(path).name}: is a directory, not a motion file; expected a file ending in {', '.join(supported)}"
        )
    ext = Path(path).suffix.lower()
    if ext not in _FORMATS:
        supported = READ_FORMATS if which == 1 else WRITE_FORMATS
        raise ValueError(
            f"{Path(path).name}: unknown motion file extension {ext or '(none)'!r}; "
            f"supported: {', '.join(supported)}"
        )
    module_name, reader, writer = _FORMATS[ext]
    name = reader if which == 1 else writer
    if name is None:
        raise ValueError(
            f"{Path(path).name}: {ext} files can be read but not written; writable: {', '.join(WRITE_FORMATS)}"
        )
    try:
        module = importlib.import_module(f"{__name__}.{module_name}")
    except ModuleNotFoundError as exc:
        if exc.name == f"{__name__}.{module_name}":
            raise ValueError(f"{Path(path).name}: the {ext} format module streamfix.io.{module_name} is not available") from None
        raise
    fn = getattr(module, name, None)
    if fn is None:
        raise ValueError(f"{Path(path).name}: streamfix.io.{module_name} has no {name}()")
    return fn


def read_motion(path: str | Path, **kwargs) -> Motion:
    """Read any supported motion file (by extension); ``kwargs`` go to the format's reader."""
    return _handler(path, 1)(path, **kwargs)


def write_motion(motion: Motion, path: str | Path, **kwargs) -> None:
    """Write a motion in the format its extension names (``.csv``, ``.bvh``, ``.c3d``, ``.sfrec``, ``.trc``)."""
    _handler(path, 2)(motion, path, **kwargs)


def check_writable(skeleton: Skeleton, path: str | Path) -> None:
    """ValueError naming why a motion of ``skeleton`` cannot be written to ``path`` (before any work).

    Only BVH restricts the layout today: it needs one tree of bones
    (:func:`streamfix.io.bvh.check_bvh_skeleton`).
    """
    if Path(path).suffix.lower() == ".bvh":
        from .bvh import check_bvh_skeleton

        check_bvh_skeleton(skeleton)
