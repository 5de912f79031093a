"""``streamfix serve``: raw skeleton frames in, ``live`` and ``clean`` frames out over ZeroMQ.

Examples::

    streamfix serve                                   # replay the demo recording in replay_data/
    streamfix serve --source tcp://127.0.0.1:5555 --out tcp://127.0.0.1:5556 --metrics-port 9556
    streamfix replay rec.csv --to tcp://127.0.0.1:5555 # feed it from another terminal
    streamfix tap tcp://127.0.0.1:5556 --topic clean   # watch the output
    kinect_bridge | streamfix serve --source stdin    # Kinect v2 CSV or JSON lines on stdin

Sources, topics, socket patterns and metrics are described in
:mod:`streamfix.service.sources`, :mod:`streamfix.service.publisher` and
:mod:`streamfix.service.server`. Endpoints bind to 127.0.0.1 unless told otherwise.
"""
from __future__ import annotations

import argparse
import logging
import sys

HELP = "run the cleaning service: raw frames in (ZeroMQ PULL, stdin or a recording), live/clean out on ZeroMQ PUB"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--source",
        default=None,
        help="tcp://HOST:PORT (the service binds a PULL; senders connect PUSH), 'stdin' "
        "(Kinect v2 CSV or JSON lines), or replay:FILE. Default: replay of the first .csv in replay_data/",
    )
    p.add_argument("--out", default="tcp://127.0.0.1:5556", help="PUB endpoint to bind (default %(default)s)")
    p.add_argument("--window", type=int, default=None, help="frames per solved window (engine default if omitted)")
    p.add_argument("--hop", type=int, default=None, help="frames between window solves (engine default if omitted)")
    p.add_argument("--lookahead", default=None, metavar="L",
                   help="lookahead of the clean output: seconds (0.5 or 0.5s) or frames (15f); "
                   "engine default (0.5 s) if omitted")
    p.add_argument("--metrics-port", type=int, default=None, metavar="P",
                   help="serve Prometheus metrics at http://127.0.0.1:P/metrics (0 = any free port; off if omitted)")
    p.add_argument("--metrics-host", default="127.0.0.1", help="address for the metrics HTTP server (default %(default)s)")
    p.add_argument("--status-interval", type=float, default=5.0, metavar="S",
                   help="seconds between one-line status reports on stderr (0 = only at exit; default %(default)s)")
    p.add_argument("--rate", type=float, default=1.0, help="replay: speed-up over the recording's timing (default 1; 0 = as fast as possible)")
    p.add_argument("--loop", action="store_true", help="replay: loop the recording instead of exiting at its end")
    p.add_argument("--start-delay", type=float, default=0.0, metavar="S",
                   help="wait S seconds before reading input, so subscribers can connect first (default 0)")
    p.add_argument("--idle-timeout", type=float, default=2.0, metavar="S",
                   help="flush a stream that sent nothing for S seconds, so its last frames come out "
                   "on clean (0 = only at exit; default %(default)s)")
    p.add_argument("--stream-id", default=None, help="stream id for stdin/replay input (default: stdin / file name)")
    p.add_argument("--sensor-rate", type=float, default=30.0,
                   help="frame rate (Hz) assumed for a stream no skeleton message describes (default %(default)s)")
    p.add_argument("--engine", default="streamfix", choices=("streamfix", "passthrough"),
                   help="per-stream engine; passthrough copies input to live/clean (baseline, default %(default)s)")
    p.add_argument("--sync", action="store_true", help="solve windows on the input thread (no worker thread)")
    p.add_argument("--sndhwm", type=int, default=1000, help="PUB send high-water mark per subscriber (messages)")
    p.add_argument("--linger-ms", type=int, default=2000, help="on exit, wait this long for queued messages to leave")
    p.add_argument("--meta-interval", type=float, default=1.0, help="seconds between repeated skeleton messages")
    p.add_argument("--prior", default=None, metavar="PATH",
                   help="learned prior to use: a model card .json or a directory holding one, as written by "
                        "`streamfix train-prior --out DIR` (default: the shipped model)")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=getattr(logging, args.log_level), stream=sys.stderr, format="streamfix serve: %(message)s"
    )
    log = logging.getLogger("streamfix.service")
    if args.prior is not None:
        from ..prior.runtime import set_default_prior

        try:
            set_default_prior(args.prior)
        except (OSError, ValueError, KeyError) as exc:
            print(f"streamfix serve: --prior {args.prior}: {exc}", file=sys.stderr)
            return 2

    from ..service.engines import EngineOptions, engine_factory, parse_lookahead
    from ..service.publisher import ServicePublisher
    from ..service.server import Service
    from ..service.sources import default_replay_file, open_source

    spec = args.source
    if spec is None:
        try:
            spec = f"replay:{default_replay_file()}"
        except FileNotFoundError as exc:
            print(f"streamfix serve: {exc}", file=sys.stderr)
            return 2
    if not args.rate >= 0:
        print(f"streamfix serve: --rate must be >= 0 (0 = as fast as possible), got {args.rate}", file=sys.stderr)
        return 2
    rate = float("inf") if args.rate == 0 else args.rate
    try:
        seconds, frames = (None, None) if args.lookahead is None else parse_lookahead(args.lookahead)
        options = EngineOptions(
            window=args.window, hop=args.hop, lookahead=seconds, lookahead_frames=frames, threaded=not args.sync
        )
        make_engine = engine_factory(args.engine, options)
    except ValueError as exc:
        print(f"streamfix serve: bad engine settings: {exc}", file=sys.stderr)
        return 2
    try:
        source = open_source(spec, rate=rate, loop=args.loop, stream_id=args.stream_id)
    except (FileNotFoundError, ValueError, RuntimeError, OSError) as exc:
        print(f"streamfix serve: cannot open source: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # zmq.ZMQError (address in use, bad endpoint)
        print(f"streamfix serve: cannot open source {spec!r}: {exc}", file=sys.stderr)
        return 2
    try:
        publisher = ServicePublisher(
            args.out, sndhwm=args.sndhwm, linger_ms=args.linger_ms, meta_interval_s=args.meta_interval
        )
    except Exception as exc:
        source.close()
        print(f"streamfix serve: cannot bind --out {args.out!r}: {exc}", file=sys.stderr)
        return 2
    try:
        service = Service(
            source,
            publisher,
            make_engine,
            default_rate_hz=args.sensor_rate,
            metrics_port=args.metrics_port,
            metrics_host=args.metrics_host,
            status_interval_s=args.status_interval,
            start_delay_s=args.start_delay,
            idle_timeout_s=args.idle_timeout,
        )
    except OSError as exc:
        publisher.close()
        source.close()
        print(f"streamfix serve: cannot serve metrics on port {args.metrics_port}: {exc}", file=sys.stderr)
        return 2
    service.install_signal_handlers()
    if not args.sync:
        # the solver thread holds the GIL in slices; shorter slices let the live path in sooner
        sys.setswitchinterval(0.0005)
    metrics = (
        f", metrics on http://{service.metrics_server.host}:{service.metrics_server.port}/metrics"
        if service.metrics_server
        else ""
    )
    log.info("ready: source %s, publishing on %s%s", source.describe(), publisher.endpoint, metrics)
    return service.run()
