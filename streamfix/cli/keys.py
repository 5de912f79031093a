"""``streamfix keys DIR``: make CURVE key pairs for authenticated, encrypted streaming.

Writes ``server.key`` / ``server.key_secret`` and one client pair per ``--client NAME``
(default ``client``) into DIR (created if missing; existing keys are never
overwritten; secret files are mode 0600). Then::

    mkdir DIR/clients && cp DIR/client.key DIR/clients/
    streamfix serve --source tcp://0.0.0.0:5555 --out tcp://0.0.0.0:5556 \\
        --curve-secret DIR/server.key_secret --curve-clients DIR/clients
    streamfix replay rec.csv --to tcp://HOST:5555 --curve-secret DIR/client.key_secret --curve-server DIR/server.key
    streamfix tap tcp://HOST:5556 --curve-secret DIR/client.key_secret --curve-server DIR/server.key

A client whose public key is not in the clients directory cannot connect: it neither
receives output nor injects input (see :mod:`streamfix.transport.curve`).
"""
from __future__ import annotations

import argparse
import sys

HELP = "make CURVE key pairs (server + clients) for `serve --curve-*` and the clients' `--curve-*`"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("directory", metavar="DIR", help="where to write the key files")
    p.add_argument("--client", action="append", default=None, metavar="NAME",
                   help="client key pair to make (repeatable; default: one named 'client')")
    p.add_argument("--no-server", action="store_true", help="only make client pairs")


def add_curve_client_arguments(p: argparse.ArgumentParser) -> None:
    """``--curve-secret`` / ``--curve-server`` for commands that connect to a CURVE service."""
    p.add_argument("--curve-secret", default=None, metavar="FILE",
                   help="this client's CURVE secret key (e.g. client.key_secret from `streamfix keys`)")
    p.add_argument("--curve-server", default=None, metavar="FILE",
                   help="the service's CURVE public key (server.key); required with --curve-secret")


def curve_client(args: argparse.Namespace):
    """The CurveClient the ``--curve-*`` options name, or None; ValueError if only one is given."""
    if args.curve_secret is None and args.curve_server is None:
        return None
    if args.curve_secret is None or args.curve_server is None:
        raise ValueError("--curve-secret and --curve-server go together")
    from ..transport.curve import CurveClient

    return CurveClient(args.curve_secret, args.curve_server)


def run(args: argparse.Namespace) -> int:
    from ..transport.curve import create_keys

    names = tuple(([] if args.no_server else ["server"]) + (args.client or ["client"]))
    if len(set(names)) != len(names):
        print(f"streamfix keys: duplicate key names in {', '.join(names)}", file=sys.stderr)
        return 2
    try:
        made = create_keys(args.directory, names)
    except (OSError, ValueError) as exc:
        print(f"streamfix keys: {exc}", file=sys.stderr)
        return 1
    for path in made:
        print(path)
    return 0
