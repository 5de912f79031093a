"""``streamfix replay FILE --to ENDPOINT``: play a recording into a service as a live sensor.

Reads any recording (Kinect v2 CSV, BVH, C3D through ``streamfix.io.read_motion``; the
project's ``.sfrec`` frame by frame, keeping every body and stream) and sends its
frames as wire ``frame`` messages on ``sf/raw/<stream>``, first announcing each
stream's skeleton with a ``skeleton`` message (so a skeleton outside the registry, e.g.
a BVH hierarchy, decodes at the service). See :mod:`streamfix.service.playback`.

Socket: a **PUSH socket that connects** to ``--to``, which is the PULL endpoint a
``streamfix serve --source tcp://...`` binds. The replay waits (up to ``--wait``) for a
receiver to connect before it starts its clock: started before the service, it would
otherwise queue its first seconds and deliver them in one burst, which a live service
sheds as too old. PUSH blocks (rather than drops) at its high-water mark, so no frame is
lost to ZeroMQ's slow-joiner effect; a slow service throttles the replay instead. On
exit the socket lingers up to ``--linger-ms`` for queued frames to be delivered.

Timing: frame ``i`` is sent at ``start + (t_i - t_0) / speed`` on the monotonic clock
(absolute schedule: no drift accumulates from sleep overshoot); ``--speed 0`` sends as
fast as the socket takes them. ``--loop`` repeats the recording with continuing
sequence numbers and sensor times, until interrupted (SIGINT/SIGTERM stop cleanly).

Nobody listening: when no receiver connected within ``--wait`` seconds, or none took a frame for
``--timeout`` seconds (PUSH blocks at its high-water mark), the replay says so and exits
1 instead of reporting frames as sent.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time

HELP = "play a recording (Kinect CSV, BVH, C3D, .sfrec) onto a service's input at its own timing (PUSH)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .config import add_config_argument

    add_config_argument(p, "replay")
    p.add_argument("file", help="recording to play")
    p.add_argument("--to", default="tcp://127.0.0.1:5555",
                   help="endpoint to connect a PUSH socket to: the service's --source (default %(default)s)")
    from .options import add_speed_argument, int_at_least, positive_number

    add_speed_argument(p, "pacing")
    p.add_argument("--loop", action="store_true", help="repeat the recording until interrupted")
    p.add_argument("--stream-id", default=None, help="stream id to send (default: the file name)")
    p.add_argument("--body-id", type=int, default=0, help="body id of the recorded body (default 0)")
    # ranges checked by the parser: ZeroMQ would refuse them later, blaming the endpoint
    p.add_argument("--sndhwm", type=int_at_least(0, "0 = no limit"), default=1000,
                   help="PUSH high-water mark (messages) before it blocks (0 = no limit)")
    p.add_argument("--linger-ms", type=int_at_least(-1, "-1 = wait forever"), default=10000,
                   help="on exit, wait up to this long for queued frames to be delivered (default %(default)s; "
                        "-1 = forever)")
    p.add_argument("--wait", type=positive_number("seconds"), default=60.0, metavar="S",
                   help="wait up to S seconds for a receiver to connect before playing (default %(default)s; "
                        "a service's first start after an install compiles its kernels first)")
    p.add_argument("--timeout", type=positive_number("seconds"), default=10.0, metavar="S",
                   help="give up (exit 1) when no receiver takes a frame for S seconds (default %(default)s)")
    p.add_argument("--quiet", action="store_true", help="no summary line on stderr")
    from .keys import add_curve_client_arguments

    add_curve_client_arguments(p)


def run(args: argparse.Namespace) -> int:
    import zmq

    from ..service.playback import Pacer, open_playback
    from ..transport.zmq_io import FramePublisher

    from .options import check_speed

    speed = check_speed("replay", args.speed)
    if speed is None:
        return 2
    try:
        playback = open_playback(args.file, stream_id=args.stream_id, body_id=args.body_id)
    except (OSError, ValueError, RuntimeError) as exc:
        print(f"streamfix replay: cannot read {args.file}: {exc}", file=sys.stderr)
        return 2
    stop = {"flag": False}

    def _stop(*_: object) -> None:
        stop["flag"] = True

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)

    from .keys import curve_client

    try:
        pub = FramePublisher(args.to, bind=False, socket_type=zmq.PUSH, sndhwm=args.sndhwm,
                             curve=curve_client(args))
    except (OSError, ValueError) as exc:
        print(f"streamfix replay: CURVE keys: {exc}", file=sys.stderr)
        return 2
    except zmq.ZMQError as exc:
        print(f"streamfix replay: cannot connect to {args.to!r}: {exc}", file=sys.stderr)
        return 2
    pub.socket.setsockopt(zmq.LINGER, int(args.linger_ms))
    pub.socket.setsockopt(zmq.SNDTIMEO, max(1, int(args.timeout * 1000)))
    peers = _PeerWatch(pub.socket, args.to)
    sent = 0
    failed = None
    t_start = time.monotonic()
    try:
        if not peers.wait(args.wait, lambda: stop["flag"]):
            frames = iter(())  # nobody came (or a signal): nothing to send; reported below
        else:
            for stream_id, skeleton, rate_hz in playback.announce:
                pub.announce(stream_id, skeleton, rate_hz)
            frames = playback.frames(args.loop)
        pacer = Pacer(speed)  # the clock starts once a receiver is there
        for t_rel, frame in frames:
            wait = pacer.wait_time(t_rel)
            while wait > 0 and not stop["flag"]:
                time.sleep(min(wait, 0.1))
                wait = pacer.wait_time(t_rel)
            if stop["flag"]:
                break
            pub.publish("raw", frame)
            sent += 1
    except zmq.Again:  # SNDHWM frames queued and nobody took one for --timeout seconds
        failed = f"no receiver at {args.to} took a frame for {args.timeout:g} s"
    finally:
        connected = peers.connected()
        peers.close()
        if not connected or failed is not None:
            pub.socket.setsockopt(zmq.LINGER, 0)  # nobody to deliver to: do not wait
        pub.close()  # lingers so queued frames reach the service
    took = time.monotonic() - t_start
    if failed is None and not connected:
        failed = f"no receiver ever connected at {args.to}"
    if failed is not None:
        print(f"streamfix replay: {failed}: {sent} frames handed to ZeroMQ, none known delivered "
              f"(is `streamfix serve --source {args.to}` running?)", file=sys.stderr)
        return 1
    if not args.quiet:
        print(
            f"streamfix replay: sent {sent} frames to {args.to} in {took:.2f} s, speed x{args.speed:g}: "
            f"{playback.describe()}",
            file=sys.stderr,
        )
    return 0


class _PeerWatch:
    """Watches a connecting socket's handshakes: did any receiver connect at all?"""

    def __init__(self, sock, endpoint: str) -> None:
        import zmq

        self._mon = sock.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED)
        self._sock = sock
        self._seen = False
        sock.disconnect(endpoint)  # connect again under the monitor, so no handshake is missed
        sock.connect(endpoint)

    def connected(self) -> bool:
        from zmq.utils.monitor import recv_monitor_message

        while not self._seen and self._mon.poll(0):
            recv_monitor_message(self._mon)
            self._seen = True
        return self._seen

    def wait(self, timeout_s: float, stopped) -> bool:
        """Block until a receiver has connected (True), ``timeout_s`` passed or ``stopped()`` (False)."""
        deadline = time.monotonic() + timeout_s
        while not self.connected():
            left = deadline - time.monotonic()
            if left <= 0 or stopped():
                return False
            self._mon.poll(int(min(left, 0.1) * 1000) + 1)
        return True

    def close(self) -> None:
        self._sock.disable_monitor()
        self._mon.close(linger=0)
