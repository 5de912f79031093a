"""Output-file checks shared by the commands that write files (``clean``, ``record``).

Every check runs before any work is done, so a command never solves for minutes and
then fails to write, and never silently loses data: the format must be writable, the
directory must exist and be writable, an existing file is replaced only with
``--overwrite``, and no command writes over one of its own inputs.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

__all__ = ["check_output"]


def check_output(
    path: str | Path,
    *,
    formats: Iterable[str],
    inputs: Iterable[str | Path] = (),
    overwrite: bool = False,
    append: bool = False,
) -> Path:
    """Return ``path`` if the command may write it; ValueError / FileExistsError saying why not.

    ``formats``: accepted extensions (``.csv``, ...). ``inputs``: files the command
    reads (never overwritten, even with ``overwrite``). ``append``: an existing file
    is continued, not replaced.
    """
    out = Path(path)
    formats = tuple(formats)
    if out.is_dir():
        raise ValueError(f"{out} is a directory; the output is a file ending in {', '.join(formats)}"
                         " (a folder of recordings is cleaned with streamfix clean DIR OUT_DIR)")
    if out.suffix.lower() not in formats:
        raise ValueError(f"{out}: cannot write {out.suffix or 'a file without extension'}; "
                         f"the output must end in {', '.join(formats)}")
    for src in inputs:
        src = Path(src)
        if out.resolve() == src.resolve() or (out.exists() and src.exists() and os.path.samefile(out, src)):
            raise ValueError(f"{out} is also the input {src}: refusing to overwrite the input "
                             "(write to another file)")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"{out}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{out}: directory {parent} is not writable")
    if out.exists():
        if out.is_dir():
            raise ValueError(f"{out} is a directory, expected a file name")
        if not (overwrite or append):
            raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
        if not os.access(out, os.W_OK):
            raise ValueError(f"{out} exists and is not writable")
    return out
