"""``streamfix view [ENDPOINT | FILE]``: watch raw versus cleaned skeletons in the browser.

Examples::

    streamfix serve --loop &                     # a service on tcp://127.0.0.1:5556
    streamfix view                               # open http://127.0.0.1:8765/
    streamfix view tcp://10.0.0.5:5556 --port 9000
    streamfix view ../shared/data/kinect_v2/Ges01_wavehand.csv   # no service needed

With an endpoint, a bridge subscribes to the service's ``raw``, ``live`` and ``clean``
topics and streams them to the page over WebSocket (see :mod:`streamfix.viewer`). With
a file, the file is played at real time (looped unless ``--once``) through the same
engines as ``streamfix serve``, on a private loopback port. The page is served on
127.0.0.1 unless ``--host`` says otherwise. Runs until Ctrl-C, ``--duration`` seconds,
or (``--once``) the end of the file.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HELP = "live browser view of raw vs cleaned skeletons from a service (ENDPOINT) or a file played through the engine"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", nargs="?", default="tcp://127.0.0.1:5556",
                   help="a service's PUB endpoint (default %(default)s) or a recording (Kinect CSV, BVH, C3D, .sfrec)")
    p.add_argument("--port", type=int, default=8765, help="HTTP/WebSocket port of the page (0 = any free port; default %(default)s)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve the page on (default %(default)s)")
    from .options import add_speed_argument

    add_speed_argument(p, "FILE", allow_zero=False)
    p.add_argument("--once", action="store_true", help="FILE: play once and exit at its end (default: loop)")
    p.add_argument("--engine", default="streamfix", choices=("streamfix", "passthrough"),
                   help="FILE: engine to clean with (default %(default)s)")
    from .options import positive_number

    p.add_argument("--duration", type=positive_number("seconds"), default=None, metavar="S", help="exit after S seconds")


def _is_endpoint(text: str) -> bool:
    return "://" in text


def run(args: argparse.Namespace) -> int:
    from ..viewer import FileService, Viewer

    if not 0 <= args.port <= 65535:
        print(f"streamfix view: --port must be 0..65535, got {args.port}", file=sys.stderr)
        return 2
    from .options import check_speed

    if check_speed("view", args.speed, allow_zero=False) is None:
        return 2
    local = None
    endpoint = args.source
    if not _is_endpoint(args.source):
        if not Path(args.source).is_file():
            print(f"streamfix view: {args.source!r} is neither an endpoint (tcp://HOST:PORT) nor a file",
                  file=sys.stderr)
            return 2
        try:
            local = FileService(args.source, rate=args.speed, loop=not args.once, engine=args.engine)
        except (OSError, ValueError, RuntimeError) as exc:
            print(f"streamfix view: cannot play {args.source}: {exc}", file=sys.stderr)
            return 2
        endpoint = local.endpoint
        sys.setswitchinterval(0.0005)  # as serve: the solver thread yields the GIL to the live path sooner
    try:
        viewer = Viewer(endpoint, args.host, args.port,
                        title=f"streamfix view {local.description if local else endpoint}")
    except OSError as exc:
        if local:
            local.close()
        print(f"streamfix view: cannot serve the page on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # zmq.ZMQError: a malformed endpoint
        if local:
            local.close()
        print(f"streamfix view: cannot subscribe to {endpoint!r}: {exc}", file=sys.stderr)
        return 2
    what = local.description if local else endpoint
    print(f"streamfix view: open {viewer.url}  (showing {what}; Ctrl-C to stop)", file=sys.stderr, flush=True)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        while deadline is None or time.monotonic() < deadline:
            if local is not None and not local.running:
                time.sleep(1.0)  # let the last clean frames reach the page
                break
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
        if local is not None:
            local.close()
    return 0
