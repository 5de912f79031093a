"""``streamfix record ENDPOINT OUT.sfrec``: subscribe and append to a recording.

Connects a SUB socket to ENDPOINT (a service's ``--out``; ``--bind`` binds a PULL
instead, to record what a ``streamfix replay`` pushes), subscribes to ``--topic``
prefixes (``raw``, ``live``, ``clean``, ``meta``, ``KIND/STREAM`` or a raw prefix;
default everything, ``sf/``) and appends every valid message to OUT in the ``.sfrec``
format (:mod:`streamfix.io.recording`), byte for byte as received. Each stream's
skeleton message is recorded when first seen and whenever it changes (not every
periodic repeat), so the file decodes on its own.

Crash safety: a frame is *acknowledged* once its record is in the kernel (one
``write(2)``); ``--ack`` prints ``ack <topic> <seq>`` on stdout at that moment. A
recorder killed at any point (SIGKILL included) leaves a file that reads back with
every acknowledged frame; SIGINT/SIGTERM close the file cleanly (fsync) and print a
summary. ``--fsync S`` bounds what a power loss can take (default 1 s).

Stops after ``--count N`` frames, after ``--duration S`` seconds, or on a signal.
Malformed messages are counted by reason, skipped, and reported on stderr.

OUT must end in ``.sfrec`` (the only format written byte for byte); an existing file
needs ``--append`` or ``--overwrite``. The endpoint is connected (or bound) before OUT is
opened, so a start that fails (a bad endpoint, a busy port) creates no file and leaves an
existing one as it was. ``--overwrite`` writes a temporary file beside OUT that takes OUT's
name at the first record (or at a clean stop): the old recording is kept until the new one
holds data, and the crash-safety promise above holds from then on. A failed write (disk
full) prints one line and exits 1; the file then holds every record acknowledged before
the error (an old recording that was to be overwritten is kept if no record was written).
A run that received no frame (nothing published, a wrong topic) says so and exits 1,
leaving no empty recording: a file it created is removed, one it was to overwrite is kept.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import time
from pathlib import Path

HELP = "subscribe to a streamfix endpoint and append messages to a crash-safe .sfrec recording"


class _Stop(Exception):
    """Raised by the SIGINT/SIGTERM handler to leave the receive loop at once."""


class _Output:
    """The recording being written: OUT itself, or (``--overwrite`` of an existing file) a
    temporary file beside it renamed over OUT by :meth:`commit`.

    Opened only after the endpoint is up, so a failed start never touches OUT.
    """

    def __init__(self, path: str, *, append: bool, overwrite: bool, fsync_interval_s: float) -> None:
        from ..archive import partial_path
        from ..io.recording import RecordingWriter

        self.path = Path(path)
        self.pending: Path | None = None  # the temporary file, until it takes OUT's name
        self.created = False  # OUT did not exist before this run (removed again if no frame came)
        if overwrite and not append and self.path.exists():
            self.pending = partial_path(self.path)
            try:
                self.writer = RecordingWriter(self.pending, overwrite=True, fsync_interval_s=fsync_interval_s)
            except BaseException:
                self.pending.unlink(missing_ok=True)
                raise
        else:
            existed = self.path.exists()
            try:
                self.writer = RecordingWriter(self.path, append=append, overwrite=overwrite,
                                              fsync_interval_s=fsync_interval_s)
            except BaseException:
                if not existed:  # created here, header not written (disk full): leave nothing behind
                    with contextlib.suppress(OSError):
                        self.path.unlink()
                raise
            self.created = not existed

    def write(self, topic: bytes, payload: bytes, recv_time_ns: int, frame: bool = True) -> None:
        """Append one record; the first frame of an overwrite moves the new file into OUT's place
        (a skeleton message alone does not: a recording without frames replaces nothing)."""
        self.writer.write(topic, payload, recv_time_ns)
        if frame and self.pending is not None:
            self.commit()

    def commit(self) -> None:
        """Rename the temporary file over OUT (atomic within the folder; the open file goes on)."""
        if self.pending is None:
            return
        self.writer.sync()
        os.replace(self.pending, self.path)
        self.pending = None
        with contextlib.suppress(OSError):  # the rename itself survives a power loss
            fd = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)

    def close(self, keep: bool, empty: bool = False) -> None:
        """Close the file; a temporary file not yet renamed takes OUT's name when ``keep``, else is
        removed; a file this run created is removed when ``empty`` (no frame was written to it)."""
        try:
            self.writer.close()
        finally:
            if self.pending is not None:
                if keep:
                    self.commit()
                else:
                    self.pending.unlink(missing_ok=True)
            elif self.created and empty:
                self.path.unlink(missing_ok=True)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .config import add_config_argument

    add_config_argument(p, "record")
    p.add_argument("endpoint", help="endpoint to connect to, e.g. tcp://127.0.0.1:5556")
    p.add_argument("out", help="recording to write (.sfrec)")
    from .options import add_list_argument, int_at_least, positive_number

    add_list_argument(p, "--topic", metavar="PREFIX",
                      help="raw, live, clean, meta, KIND/STREAM or a raw prefix; several as 'a b', 'a,b' or a "
                           "repeated --topic (default: sf/, everything)")
    p.add_argument("--count", type=int_at_least(1), default=None, help="stop after N frames")
    p.add_argument("--duration", type=positive_number("seconds"), default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--append", action="store_true", help="append to an existing recording (a torn tail is cut off)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file")
    p.add_argument("--fsync", type=positive_number("seconds", zero="every record"), default=1.0, metavar="S",
                   help="fsync at most every S seconds (0 = every record; default %(default)s)")
    p.add_argument("--ack", action="store_true", help="print 'ack TOPIC SEQ' on stdout once each frame is in the file")
    p.add_argument("--bind", action="store_true", help="bind a PULL socket instead of connecting a SUB")
    p.add_argument("--quiet", action="store_true", help="no per-error lines and no summary on stderr")
    from .keys import add_curve_client_arguments

    add_curve_client_arguments(p)


def run(args: argparse.Namespace) -> int:
    import zmq

    from ..transport.wire import SkeletonMessage, resolve_topic_arg, topic_prefix
    from ..transport.zmq_io import Subscriber

    topics = [resolve_topic_arg(t) for t in (args.topic or ["sf/"])]
    meta = topic_prefix("meta")

    def on_error(topic: bytes, error) -> None:
        if not args.quiet:
            print(f"streamfix record: skipped message on {topic.decode('ascii', 'replace')!r} "
                  f"({error.reason}): {error}", file=sys.stderr, flush=True)

    from .keys import curve_client
    from .outputs import check_output

    try:
        check_output(args.out, formats=(".sfrec",), overwrite=args.overwrite, append=args.append)
    except (OSError, ValueError) as exc:
        print(f"streamfix record: cannot open {args.out}: {exc}"
              + (" (use --append or --overwrite)" if isinstance(exc, FileExistsError) else ""), file=sys.stderr)
        return 2
    try:
        curve = curve_client(args)
    except (OSError, ValueError) as exc:
        print(f"streamfix record: CURVE keys: {exc}", file=sys.stderr)
        return 2
    try:  # the endpoint first: a start that fails must not create, truncate or replace OUT
        sub = Subscriber(args.endpoint, topics + [meta], bind=args.bind,
                         socket_type=zmq.PULL if args.bind else zmq.SUB, on_error=on_error, curve=curve)
    except zmq.ZMQError as exc:
        print(f"streamfix record: cannot {'bind' if args.bind else 'connect to'} {args.endpoint!r}: {exc}",
              file=sys.stderr)
        return 2
    try:
        out = _Output(args.out, append=args.append, overwrite=args.overwrite, fsync_interval_s=args.fsync)
    except (OSError, ValueError) as exc:
        sub.close()
        print(f"streamfix record: cannot open {args.out}: {exc}"
              + (" (use --append or --overwrite)" if isinstance(exc, FileExistsError) else ""), file=sys.stderr)
        return 2
    except BaseException:
        sub.close()
        raise
    writer = out.writer

    def _handler(signum, _frame):
        raise _Stop(signum)

    old = {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM)}
    frames = 0
    last_meta: dict[str, tuple] = {}
    t0 = time.monotonic()
    reason = "done"
    failed = None
    ended = False  # stopped by --count, --duration or a signal: what was recorded is OUT now
    try:
        while args.count is None or frames < args.count:
            remaining = None
            if args.duration is not None:
                remaining = args.duration - (time.monotonic() - t0)
                if remaining <= 0:
                    reason = "duration reached"
                    break
            for rec in sub.receive(count=1, timeout_s=remaining if remaining is not None else 0.5):
                msg = rec.message
                if isinstance(msg, SkeletonMessage):
                    key = (msg.skeleton, msg.rate_hz, msg.units)
                    if last_meta.get(msg.stream_id) == key:
                        continue  # a periodic repeat: already in the file
                    last_meta[msg.stream_id] = key
                    out.write(rec.topic, rec.payload, rec.recv_time_ns, frame=False)
                    continue
                if not any(rec.topic.startswith(t) for t in topics):
                    continue
                out.write(rec.topic, rec.payload, rec.recv_time_ns)
                frames += 1
                if args.ack:
                    print(f"ack {rec.topic.decode('ascii')} {msg.seq}", flush=True)
        else:
            reason = "count reached"
        ended = True
    except _Stop as stop:
        reason = f"signal {signal.Signals(stop.args[0]).name}"
        ended = True
    except OSError as exc:  # disk full, file too large, I/O error: every record before it is readable
        failed = f"writing {args.out} failed after {frames} frames: {exc.strerror or exc}"
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        kept_old = out.pending is not None and not (ended and frames)  # nothing of this run reached OUT
        removed = out.created and not frames
        try:
            out.close(keep=ended and frames > 0, empty=not frames)
        except OSError as exc:
            failed = failed or f"closing {args.out} failed after {frames} frames: {exc.strerror or exc}"
        sub.close()
    if failed:
        where = (f"{args.out} is left as it was" if kept_old else "it was not created" if removed
                 else "the file holds every frame acknowledged before the error")
        print(f"streamfix record: {failed}; {where}", file=sys.stderr)
        return 1
    if not frames:  # nothing came: say so, and leave no empty recording in OUT's place
        where = ("it was not created" if removed else f"{args.out} is left as it was" if kept_old
                 else f"{args.out} holds no new frame")
        print(f"streamfix record: no frame received from {args.endpoint} ({reason}); {where}", file=sys.stderr)
        return 1
    if not args.quiet:
        c = sub.counters
        print(
            f"streamfix record: {reason}: {frames} frames and {len(last_meta)} skeleton messages written to "
            f"{args.out} ({writer.records} records this run, {writer.bytes_written} bytes); "
            f"{c['malformed']} malformed messages skipped",
            file=sys.stderr,
        )
    return 0
