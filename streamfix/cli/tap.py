"""``streamfix tap ENDPOINT``: subscribe to a streamfix PUB and print decoded messages.

The Python reference subscriber's command-line face. Connects a SUB socket to
ENDPOINT (a service's ``--out``), subscribes to ``--topic`` prefixes (``raw``,
``live``, ``clean``, ``meta``, ``live/kinect0`` or any raw prefix such as ``sf/``) and
prints one line per message; ``--json`` prints one JSON object per line::

    {"topic": "sf/live/kinect0", "kind": "live", "stream": "kinect0", "type": "frame",
     "seq": 12, "t_sensor_ns": ..., "t_publish_ns": ..., "latency_ms": 0.4,
     "skeleton": "kinect_v2", "filled": false,
     "bodies": [{"id": 1, "joints": [[x, y, z] | null, ...], "confidence": [...],
                 "recovered": [false, ...] | null}]}

Skeleton messages (``type: "skeleton"``) are printed when ``meta`` is subscribed.
Malformed messages are counted by reason, skipped, and reported on stderr (one line
each, and a summary at exit). ``--count N`` stops after N printed messages,
``--duration S`` after S seconds (as in ``record`` and ``view``; the old spelling
``--timeout`` still works). Exit status 0, or 2 when ``--count`` was not reached
before then (or the endpoint is unusable).
"""
from __future__ import annotations

import argparse
import json
import math
import sys

HELP = "subscribe to a streamfix endpoint and print decoded messages (--json: one object per line)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("endpoint", help="endpoint of a streamfix PUB to connect to, e.g. tcp://127.0.0.1:5556")
    from .options import add_list_argument, int_at_least, positive_number

    add_list_argument(p, "--topic", metavar="PREFIX",
                      help="raw, live, clean, meta, KIND/STREAM, or a raw topic prefix; several as 'a b', 'a,b' or a "
                           "repeated --topic (default: live and clean)")
    p.add_argument("--count", type=int_at_least(1), default=None, help="stop after N messages")
    p.add_argument("--duration", "--timeout", dest="duration", type=positive_number("seconds"), default=None, metavar="S",
                   help="stop after S seconds")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--bind", action="store_true",
                   help="bind a PULL socket instead of connecting a SUB (receive what a replay sends)")
    from .keys import add_curve_client_arguments

    add_curve_client_arguments(p)


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def frame_to_json(received) -> dict:
    """The JSON form of one received frame or skeleton message (see module doc)."""
    from ..transport.wire import SkeletonMessage

    msg = received.message
    out = {"topic": received.topic.decode("ascii", "replace"), "kind": received.kind, "stream": received.stream}
    if isinstance(msg, SkeletonMessage):
        out.update({
            "type": "skeleton",
            "skeleton": msg.skeleton.name,
            "joint_names": list(msg.skeleton.joint_names),
            "bones": [list(b) for b in msg.skeleton.bones],
            "rate_hz": msg.rate_hz,
            "units": msg.units,
            "t_publish_ns": msg.publish_time_ns,
        })
        return out
    latency = (received.recv_time_ns - msg.publish_time_ns) / 1e6 if msg.publish_time_ns else None
    bodies = []
    for b in msg.bodies:
        joints = [None if not all(math.isfinite(c) for c in row) else [float(c) for c in row]
                  for row in b.positions.tolist()]
        bodies.append({
            "id": b.body_id,
            "joints": joints,
            "confidence": [float(c) for c in b.confidence.tolist()],
            "recovered": None if b.recovered is None else [bool(r) for r in b.recovered.tolist()],
        })
    out.update({
        "type": "frame",
        "seq": msg.seq,
        "t_sensor_ns": msg.sensor_time_ns,
        "t_publish_ns": msg.publish_time_ns,
        "latency_ms": None if latency is None else round(latency, 3),
        "skeleton": msg.skeleton,
        "filled": msg.filled,
        "bodies": bodies,
    })
    if msg.epoch:
        out["epoch"] = msg.epoch
    if msg.dropped:
        out["dropped"] = msg.dropped
    return out


def frame_to_line(received) -> str:
    """``<topic> seq=.. t_sensor_ns=.. bodies=k <id>:<observed>/<recovered>/<missing> ... [filled]``."""
    import numpy as np

    from ..transport.wire import SkeletonMessage

    msg = received.message
    topic = received.topic.decode("ascii", "replace")
    if isinstance(msg, SkeletonMessage):
        return (f"{topic} skeleton={msg.skeleton.name} joints={msg.skeleton.n_joints} "
                f"bones={msg.skeleton.n_bones} rate_hz={msg.rate_hz:g}")
    parts = [f"{topic} seq={msg.seq} t_sensor_ns={msg.sensor_time_ns} bodies={len(msg.bodies)}"]
    for b in msg.bodies:  # <id>:<observed>/<recovered>/<missing>, as the reference subscribers print
        missing = np.isnan(b.positions).any(axis=1)
        rec = np.zeros_like(missing) if b.recovered is None else b.recovered & ~missing
        parts.append(f"{b.body_id}:{int((~missing & ~rec).sum())}/{int(rec.sum())}/{int(missing.sum())}")
    if msg.filled:
        parts.append("filled")
    if msg.dropped:
        parts.append(f"dropped={msg.dropped}")
    if msg.publish_time_ns:
        parts.append(f"latency_ms={(received.recv_time_ns - msg.publish_time_ns) / 1e6:.2f}")
    return " ".join(parts)


def run(args: argparse.Namespace) -> int:
    import zmq

    from ..transport.wire import resolve_topic_arg
    from ..transport.zmq_io import Subscriber

    topics = [resolve_topic_arg(t) for t in (args.topic or ["live", "clean"])]

    def on_error(topic: bytes, error) -> None:
        print(f"streamfix tap: skipped message on {topic.decode('ascii', 'replace')!r} ({error.reason}): {error}",
              file=sys.stderr, flush=True)

    from .keys import curve_client

    try:
        curve = curve_client(args)
    except (OSError, ValueError) as exc:
        print(f"streamfix tap: CURVE keys: {exc}", file=sys.stderr)
        return 2
    try:
        sub = Subscriber(args.endpoint, topics, bind=args.bind,
                         socket_type=zmq.PULL if args.bind else zmq.SUB, on_error=on_error, curve=curve)
    except zmq.ZMQError as exc:
        print(f"streamfix tap: cannot {'bind' if args.bind else 'connect to'} {args.endpoint!r}: {exc}", file=sys.stderr)
        return 2
    printed = 0
    try:
        for received in sub.receive(count=args.count, timeout_s=args.duration):
            if args.json:
                line = json.dumps(frame_to_json(received), allow_nan=False, separators=(",", ":"))
            else:
                line = frame_to_line(received)
            try:
                print(line, flush=True)
            except BrokenPipeError:  # `streamfix tap ... | head`
                return 0
            printed += 1
    except KeyboardInterrupt:
        pass
    finally:
        sub.close()
    c = sub.counters
    # the malformed count by reason (not the topics a PULL socket received and the filter left out)
    bad = {k: v for k, v in c.items()
           if k not in ("received", "frames", "skeletons", "malformed", "ignored_type", "filtered")}
    filtered = f", {c['filtered']} on other topics" if c.get("filtered") else ""
    print(
        f"streamfix tap: {printed} printed, {c['frames']} frames, {c['skeletons']} skeleton messages, "
        f"{c['malformed']} malformed{' ' + json.dumps(bad) if bad else ''}, {c['ignored_type']} unknown type"
        f"{filtered}",
        file=sys.stderr,
    )
    if args.count is not None and printed < args.count:
        return 2
    return 0
