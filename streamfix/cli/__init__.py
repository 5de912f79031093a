"""The ``streamfix`` command: one sub-command per module in this package.

Each sub-command module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``run(args) -> int``. Modules are imported only when their command runs, so that
``streamfix tap`` does not pay for scipy and ``streamfix clean`` not for zmq.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

from ..allocator import keep_freed_memory

# command name -> module under streamfix.cli
COMMANDS = {
    "serve": "serve",
    "clean": "clean",
    "eval": "evaluate",
    "replay": "replay",
    "record": "record",
    "tap": "tap",
    "train-prior": "train_prior",
    "train-bias": "train_bias",
    "view": "view",      # streamfix/viewer (browser viewer)
    "report": "report",  # streamfix/report (plotted reports)
    "keys": "keys",
}


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(prog="streamfix", description="Real-time skeleton cleaning.")
    parser.add_argument("--version", action="version", version=f"streamfix {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module_name in COMMANDS.items():
        try:
            module = importlib.import_module(f"streamfix.cli.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"streamfix.cli.{module_name}":
                continue  # command not built yet
            raise
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command. Ctrl-C while it starts (its imports, opening files and sockets) or
    runs exits 130 with one line, no traceback (commands that stop cleanly on a signal
    handle it themselves); a reader that closes the pipe early (``... --json | head``)
    ends the command quietly with 141, the shell's status for SIGPIPE."""
    try:
        parser = build_parser()
        argv = sys.argv[1:] if argv is None else list(argv)
        if "--config" in argv or any(a.startswith("--config=") for a in argv):
            from .config import ConfigError, apply_config

            try:
                apply_config(parser, argv)
            except ConfigError as exc:
                print(f"streamfix {argv[0]}: {exc}", file=sys.stderr)
                return 2
        args = parser.parse_args(argv)
        if not getattr(args, "_run", None):
            parser.print_help()
            return 2
        keep_freed_memory()  # window arrays reuse freed pages instead of faulting in new ones
        code = int(args._run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, inside the handler below
        return code
    except KeyboardInterrupt:
        print("streamfix: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Python would complain again when it flushes stdout at exit: point stdout at /dev/null
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
