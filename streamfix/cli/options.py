"""Command-line options shared by several commands (one parser rule, one error message)."""
from __future__ import annotations

import sys

__all__ = ["apply_prior_option"]


def apply_prior_option(command: str, path: str | None) -> bool:
    """``--prior PATH``: make the user's trained prior the default one; False (after one
    line on stderr naming the command and the path) when it cannot be loaded."""
    if path is None:
        return True
    from ..prior.runtime import set_default_prior

    try:
        set_default_prior(path)
    except (OSError, ValueError, KeyError) as exc:
        print(f"streamfix {command}: --prior {path}: {exc}", file=sys.stderr)
        return False
    return True
