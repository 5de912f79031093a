"""``streamfix serve``: raw skeleton frames in, ``live`` and ``clean`` frames out over ZeroMQ.

Examples::

    streamfix serve                                   # replay the demo recording in replay_data/
    streamfix serve --source tcp://127.0.0.1:5555 --out tcp://127.0.0.1:5556 --metrics-port 9556
    streamfix serve --source rec.csv --speed 2        # replay a recording at twice its speed
    streamfix serve --source depthai:model=ID         # an OAK camera's spatial pose keypoints
    streamfix replay rec.csv --to tcp://127.0.0.1:5555 # feed it from another terminal
    streamfix tap tcp://127.0.0.1:5556 --topic clean   # watch the output
    kinect_bridge | streamfix serve --source stdin    # Kinect v2 CSV or JSON lines on stdin

Sources, topics, socket patterns and metrics are described in
:mod:`streamfix.service.sources`, :mod:`streamfix.service.publisher` and
:mod:`streamfix.service.server`; resource limits in :mod:`streamfix.service.limits`.
Endpoints bind to 127.0.0.1 unless told otherwise. Binding anything else requires CURVE
(``--curve-secret`` and ``--curve-clients``, keys from ``streamfix keys``) or an explicit
``--insecure``; the metrics endpoint on a non-loopback host is allowed with a warning
(it carries counts, no data).
"""
from __future__ import annotations

import argparse
import logging
import sys

HELP = "run the cleaning service: raw frames in (ZeroMQ PULL, stdin or a recording), live/clean out on ZeroMQ PUB"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .config import add_config_argument
    from .options import int_at_least, positive_number

    add_config_argument(p, "serve")
    p.add_argument(
        "--source",
        default=None,
        help="tcp://HOST:PORT (the service binds a PULL; senders connect PUSH), 'stdin' "
        "(Kinect v2 CSV or JSON lines), depthai[:model=ID,fps=HZ,device=ID] (an OAK camera's spatial "
        "pose keypoints), azure-kinect (live; needs an optional binding), or a recording: FILE or "
        "replay:FILE (Kinect CSV, Azure Kinect JSON, BVH, C3D, .sfrec). Default: replay of the first .csv in "
        "replay_data/",
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
    from .options import add_sensor_bias_argument, add_speed_argument

    add_speed_argument(p, "replayed recording")
    p.add_argument("--loop", action="store_true", help="replay: loop the recording instead of exiting at its end")
    p.add_argument("--start-delay", type=float, default=0.0, metavar="S",
                   help="wait S seconds before reading input, so subscribers can connect first (default 0)")
    p.add_argument("--idle-timeout", type=float, default=2.0, metavar="S",
                   help="flush a stream that sent nothing for S seconds, so its last frames come out "
                   "on clean (0 = only at exit; default %(default)s)")
    p.add_argument("--stream-id", default=None, help="stream id for stdin/replay input (default: stdin / file name)")
    p.add_argument("--sensor-rate", type=positive_number("Hz"), default=30.0,
                   help="frame rate (Hz) assumed for a stream no skeleton message describes (default %(default)s)")
    p.add_argument("--engine", default="streamfix", choices=("streamfix", "passthrough"),
                   help="per-stream engine; passthrough copies input to live/clean (baseline, default %(default)s)")
    p.add_argument("--sync", action="store_true", help="solve windows on the input thread (no worker thread)")
    p.add_argument("--solver-process", action="store_true",
                   help="solve each stream's windows in a child process (the worker thread waits without the "
                        "GIL, so the live path is not held up by the solve; same output)")
    p.add_argument("--sndhwm", type=int_at_least(0, "0 = no limit"), default=1000,
                   help="PUB send high-water mark per subscriber (messages; 0 = no limit)")
    p.add_argument("--linger-ms", type=int_at_least(-1, "-1 = wait forever"), default=2000,
                   help="on exit, wait this long for queued messages to leave (-1 = forever)")
    p.add_argument("--meta-interval", type=positive_number("seconds"), default=1.0,
                   help="seconds between repeated skeleton messages")
    p.add_argument("--prior", default=None, metavar="PATH",
                   help="learned prior to use: a model card .json or a directory holding one, as written by "
                        "`streamfix train-prior --out DIR` (default: the shipped model)")
    add_sensor_bias_argument(p)
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    p.add_argument("--view", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                   help="also serve the browser viewer (streamfix view) on http://127.0.0.1:PORT (default 8765)")
    out = p.add_argument_group("outputs beside ZeroMQ (docs/OUTPUTS.md; need the 'outputs' extra)")
    out.add_argument("--vmc", nargs="?", const="127.0.0.1:39539", default=None, metavar="[HOST:]PORT",
                     help="also send one body as VMC bone rotations (OSC over UDP) to HOST:PORT "
                     "(default 127.0.0.1:39539 when given without a value)")
    out.add_argument("--lsl", default=None, metavar="NAME",
                     help="also open an LSL outlet of type MoCap named NAME (one per stream; XDF channel metadata)")
    out.add_argument("--output-topic", default="clean", choices=("clean", "live"),
                     help="which output --vmc and --lsl carry: clean (refined, lookahead behind) or live "
                     "(lowest latency; default %(default)s)")
    lim = p.add_argument_group("limits (each hit is counted in streamfix_limit_hits_total)")
    d = _limit_defaults()
    lim.add_argument("--max-message-bytes", type=int, default=d.max_message_bytes, metavar="N",
                     help="largest input message (default %(default)s)")
    lim.add_argument("--max-streams", type=int, default=d.max_streams, metavar="N",
                     help="streams served at once (default %(default)s)")
    lim.add_argument("--max-bodies", type=int, default=d.max_bodies_per_stream, metavar="N",
                     help="body ids tracked per stream (default %(default)s)")
    lim.add_argument("--max-bodies-total", type=int, default=d.max_bodies_total, metavar="N",
                     help="body ids tracked over all streams (default %(default)s)")
    lim.add_argument("--max-joint-rate", type=float, default=d.max_joint_rate, metavar="N",
                     help="sum of joints x sensor rate over tracked bodies (bounds the engines' memory; "
                     "default %(default)s)")
    lim.add_argument("--max-rate", type=positive_number("Hz"), default=d.max_rate_hz, metavar="HZ",
                     help="highest accepted sensor rate, Hz (default %(default)s)")
    lim.add_argument("--max-coordinate", type=float, default=d.max_coordinate_m, metavar="M",
                     help="joints with a coordinate beyond M metres are missing (default %(default)s)")
    lim.add_argument("--overload", default="shed", choices=("shed", "block"),
                     help="ZeroMQ input beyond the backlog bound: shed the oldest frames, counted, so live output "
                     "stays current (live sensors), or block the producer, losing nothing (bulk replays); "
                     "default %(default)s")
    lim.add_argument("--backlog-frames", type=int, default=2000, metavar="N",
                     help="input messages waiting before the oldest are shed / the producer blocks "
                     "(default %(default)s)")
    lim.add_argument("--backlog-seconds", type=float, default=0.05, metavar="S",
                     help="shed: input older than S seconds is dropped, except each stream's newest frame "
                     "(default %(default)s)")
    lim.add_argument("--drain-timeout", type=float, default=2.0, metavar="S",
                     help="on SIGTERM, handle received input for at most S seconds; the rest is counted "
                     "as shed (default %(default)s)")
    lim.add_argument("--flush-timeout", type=float, default=10.0, metavar="S",
                     help="on exit, wait at most S seconds for windows being solved (default %(default)s)")
    sec = p.add_argument_group("security")
    sec.add_argument("--curve-secret", default=None, metavar="FILE",
                     help="the service's CURVE secret key (server.key_secret from `streamfix keys`): "
                     "encrypt and authenticate --source and --out")
    sec.add_argument("--curve-clients", default=None, metavar="DIR",
                     help="directory of allowed client public keys (*.key); required with --curve-secret")
    sec.add_argument("--insecure", action="store_true",
                     help="allow binding a non-loopback address without CURVE (anyone reaching it can inject and read)")


def _limit_defaults():
    from ..service.limits import Limits

    return Limits()


def _check_exposure(args: argparse.Namespace, spec: str, curve) -> str | None:
    """An error message if a non-loopback endpoint would be bound without CURVE and without --insecure."""
    from ..transport.curve import is_loopback_endpoint

    exposed = [e for e in (args.out, spec) if "://" in e and not is_loopback_endpoint(e)]
    if exposed and curve is None and not args.insecure:
        return (f"refusing to bind {', '.join(exposed)} without authentication: anyone who can reach it could "
                "inject frames and read the output. Use --curve-secret/--curve-clients (keys: `streamfix keys DIR`) "
                "or pass --insecure")
    return None


def _open_sinks(args: argparse.Namespace) -> list:
    """The --vmc / --lsl outputs; ValueError/ImportError saying what is wrong (bad target, missing package)."""
    from ..service.sinks import LslSink, VmcSink

    sinks = []
    if getattr(args, "vmc", None) is not None:
        from ..transport.vmc import parse_host_port

        host, port = parse_host_port(args.vmc)
        sinks.append(VmcSink(host, port, args.output_topic))
    if getattr(args, "lsl", None) is not None:
        sinks.append(LslSink(args.lsl, args.output_topic))
    return sinks


def _check_sensor_rate(args: argparse.Namespace) -> str | None:
    """What is wrong with ``--sensor-rate`` against the accepted rates, or None. Checked before
    anything starts: a rate the limits refuse would start the service and then refuse every frame."""
    from ..service.limits import Limits

    lowest = min(Limits().min_rate_hz, args.max_rate)  # as the service's limits are built below
    if not lowest <= args.sensor_rate <= args.max_rate:
        return (f"--sensor-rate must be a rate from {lowest:g} Hz to --max-rate ({args.max_rate:g} Hz), "
                f"got {args.sensor_rate:g}")
    return None


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=getattr(logging, args.log_level), stream=sys.stderr, format="streamfix serve: %(message)s"
    )
    log = logging.getLogger("streamfix.service")
    from ..service.sources import check_source, default_replay_file, open_source

    spec = args.source
    if spec is None:
        try:
            spec = f"replay:{default_replay_file()}"
        except FileNotFoundError as exc:
            print(f"streamfix serve: {exc}", file=sys.stderr)
            return 2
    try:  # first: a camera not attached or a mistyped file is said before seconds go to building the engine
        check_source(spec)
    except (OSError, ValueError, RuntimeError) as exc:
        print(f"streamfix serve: cannot open source: {exc}", file=sys.stderr)
        return 2
    from .options import apply_prior_option, check_sensor_bias_option, check_speed

    if not apply_prior_option("serve", args.prior) or not check_sensor_bias_option("serve", args.sensor_bias):
        return 2

    import zmq

    from ..service.backlog import Backlog
    from ..service.engines import EngineOptions, engine_factory, parse_lookahead
    from ..service.limits import Limits
    from ..service.publisher import ServicePublisher
    from ..service.server import Service
    from ..transport.curve import CurveServer, is_loopback_endpoint

    speed = check_speed("serve", args.speed)
    if speed is None:
        return 2
    problem = _check_sensor_rate(args)
    if problem:
        print(f"streamfix serve: {problem}", file=sys.stderr)
        return 2
    try:  # checked now, before anything is built or opened
        seconds, frames = (None, None) if args.lookahead is None else parse_lookahead(args.lookahead)
        options = EngineOptions(
            window=args.window, hop=args.hop, lookahead=seconds, lookahead_frames=frames, threaded=not args.sync,
            solver_process=args.solver_process, sensor_bias=args.sensor_bias,
        )
    except ValueError as exc:
        print(f"streamfix serve: bad engine settings: {exc}", file=sys.stderr)
        return 2
    try:
        d = Limits()
        limits = Limits(
            max_message_bytes=args.max_message_bytes, max_streams=args.max_streams,
            max_bodies_per_stream=args.max_bodies, max_bodies_total=args.max_bodies_total,
            max_joint_rate=args.max_joint_rate,
            max_bodies_per_frame=min(d.max_bodies_per_frame, args.max_bodies), max_rate_hz=args.max_rate,
            min_rate_hz=min(d.min_rate_hz, args.max_rate), max_coordinate_m=args.max_coordinate,
        )
        backlog = Backlog(args.backlog_frames, args.backlog_seconds, args.overload)
    except ValueError as exc:
        print(f"streamfix serve: bad limits: {exc}", file=sys.stderr)
        return 2
    curve = None
    if (args.curve_secret is None) != (args.curve_clients is None):
        print("streamfix serve: --curve-secret and --curve-clients go together", file=sys.stderr)
        return 2
    if args.curve_secret is not None:
        try:
            curve = CurveServer(args.curve_secret, args.curve_clients)
        except (OSError, ValueError) as exc:
            print(f"streamfix serve: CURVE keys: {exc}", file=sys.stderr)
            return 2
    problem = _check_exposure(args, spec, curve)
    if problem:
        print(f"streamfix serve: {problem}", file=sys.stderr)
        return 2
    if not is_loopback_endpoint(f"tcp://{args.metrics_host}:0") and args.metrics_port is not None:
        log.warning("metrics are served on %s, reachable from other machines (counts only, no frames)",
                    args.metrics_host)
    try:
        sinks = _open_sinks(args)
    except (ImportError, ValueError, OSError) as exc:
        print(f"streamfix serve: {exc}", file=sys.stderr)
        return 2
    # the engine is ready (imports, compiled kernels, the prior) before the source opens: a
    # bound input socket or a stdin reader stamps frames as they arrive, and frames that waited
    # for a first run's kernel compile (slow after an install) were shed as too old
    try:
        make_engine = engine_factory(args.engine, options)
    except ValueError as exc:
        if curve is not None:
            curve.stop()
        print(f"streamfix serve: bad engine settings: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a solver process that cannot start (--solver-process)
        if curve is not None:
            curve.stop()
        print(f"streamfix serve: cannot start the engine: {exc}", file=sys.stderr)
        return 2
    ctx = zmq.Context.instance()
    try:
        source = open_source(spec, speed=speed, loop=args.loop, stream_id=args.stream_id, context=ctx,
                             limits=limits, backlog=backlog, curve=curve)
    except Exception as exc:  # OSError, ValueError, RuntimeError; zmq.ZMQError (address in use, bad endpoint)
        if curve is not None:
            curve.stop()
        what = "" if isinstance(exc, (FileNotFoundError, ValueError, RuntimeError, OSError)) else f" {spec!r}"
        print(f"streamfix serve: cannot open source{what}: {exc}", file=sys.stderr)
        return 2
    try:
        publisher = ServicePublisher(
            args.out, sndhwm=args.sndhwm, linger_ms=args.linger_ms, meta_interval_s=args.meta_interval,
            context=ctx, curve=curve,
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
            status_at_exit=True,  # --status-interval 0: only at exit (its help)
            start_delay_s=args.start_delay,
            idle_timeout_s=args.idle_timeout,
            flush_timeout_s=args.flush_timeout,
            limits=limits,
            sinks=sinks,
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
    secured = ", CURVE on" if curve is not None else ""
    log.info("ready: source %s, publishing on %s%s%s", source.describe(), publisher.endpoint, metrics, secured)
    viewer = None
    if args.view is not None:  # --view: the browser viewer beside the service (streamfix/viewer)
        from ..viewer import Viewer

        try:
            viewer = Viewer(publisher.endpoint, port=args.view, title=f"streamfix serve {source.describe()}")
            log.info("viewer: open %s", viewer.url)
        except OSError as exc:
            service.close()
            if curve is not None:
                curve.stop()
            print(f"streamfix serve: --view: cannot serve the viewer on port {args.view}: {exc}", file=sys.stderr)
            return 2
    watch = f"open {viewer.url} in a browser, or run" if viewer is not None else "run"
    if curve is None:
        log.info("watch it: %s `streamfix tap %s --topic clean --count 5 --json` (or `streamfix view %s`); "
                 "stop it: Ctrl-C", watch, publisher.endpoint, publisher.endpoint)
    else:  # a client without keys cannot connect (it would wait silently); the viewer has no CURVE client
        public = args.curve_secret[: -len("_secret")] if args.curve_secret.endswith("_secret") else "SERVER.key"
        log.info("watch it: %s `streamfix tap %s --topic clean --count 5 --json --curve-secret CLIENT.key_secret "
                 "--curve-server %s` (a client key from `streamfix keys`); stop it: Ctrl-C", watch,
                 publisher.endpoint, public)
    try:
        code = service.run(drain_timeout_s=args.drain_timeout)
        if source.exhausted:
            log.info("input ended (%s): every frame was flushed to clean; exiting", source.describe())
        return code
    finally:
        if viewer is not None:
            viewer.close()
        if curve is not None:
            curve.stop()
