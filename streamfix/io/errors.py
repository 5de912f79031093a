"""The one error type of the file-format layer.

Every reader raises :class:`MotionFileError` (a ``ValueError``) for malformed input,
and its message always names the file, where in it (line for text formats, frame for
C3D) and what was expected versus what arrived, e.g.::

    Ges01.csv line 17: expected 101 fields (timestamp + 25 x 4), got 97
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["MotionFileError"]


class MotionFileError(ValueError):
    """Malformed motion file. ``path``, ``line`` / ``frame`` locate the problem."""

    def __init__(
        self,
        path: str | Path,
        what: str,
        *,
        line: int | None = None,
        frame: int | None = None,
    ) -> None:
        self.path = str(path)
        self.line = line
        self.frame = frame
        self.what = what
        where = Path(self.path).name
        if line is not None:
            where += f" line {line}"
        if frame is not None:
            where += f" frame {frame}"
        super().__init__(f"{where}: {what}")
