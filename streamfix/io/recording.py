"""The project's recording format ``.sfrec``: wire messages, append-only, crash-safe.

Layout (all integers little-endian)::

    header   8 bytes   b"SFREC" 0x00, uint16 format version (1)
    record   uint32 n  length of the body in bytes (1 .. 64 MiB)
             uint32 c  CRC-32 (zlib/IEEE) of the body
             n bytes   body: msgpack array [topic: bin, payload: bin, t_recv_ns: int]
    record   ...

``payload`` is a wire message exactly as sent on ZeroMQ (``protocol/SPEC.md``): the
stream's skeleton message first, then frame messages, so a recording is decodable
without out-of-band knowledge and replays byte for byte. ``t_recv_ns`` is the wall
clock when the recorder received it (0 for files written from a motion).

Crash safety: each record goes to the kernel in one ``write(2)`` on an ``O_APPEND``
descriptor before the writer returns, so a process that is killed (even SIGKILL)
leaves every record it acknowledged in the file; ``fsync`` runs at most every
``fsync_interval_s`` seconds (default 1 s) and on close, bounding what a power loss
can take. A reader returns every complete record and stops cleanly at a torn last
record (short header, short body); a complete record whose CRC fails is skipped and
counted; a length above the limit ends the read (the rest cannot be framed). Opening a
writer with ``append=True`` cuts a torn tail off before appending.

Readers: :func:`iter_records` (raw records), :func:`read_recording_frames`
(``SkeletonFrame`` list + metadata), :func:`read_recording` / :func:`read_motion_sfrec`
(one body of one stream as a :class:`~streamfix.motion.Motion`, what
``streamfix.io.read_motion`` dispatches to). Writers: :class:`RecordingWriter`,
:func:`write_recording` / :func:`write_motion_sfrec`.
"""
from __future__ import annotations

import os
import struct
import time
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import msgpack
import numpy as np

from ..frames import BodyFrame, SkeletonFrame
from ..motion import Motion
from ..skeletons import Skeleton, get_skeleton
from ..transport.wire import (
    SkeletonMessage,
    WireError,
    decode_message,
    encode_frame,
    encode_skeleton_message,
    parse_topic,
    topic_for,
)
from .errors import MotionFileError

__all__ = [
    "MAGIC",
    "FORMAT_VERSION",
    "RecordingWriter",
    "Record",
    "RecordingScan",
    "iter_records",
    "scan_recording",
    "read_recording_frames",
    "read_recording",
    "read_motion_sfrec",
    "write_recording",
    "write_motion_sfrec",
]

FORMAT_VERSION = 1
MAGIC = b"SFREC\x00"
HEADER = MAGIC + struct.pack("<H", FORMAT_VERSION)
_REC_HEAD = struct.Struct("<II")
MAX_RECORD_BYTES = 64 * 1024 * 1024


@dataclass
class Record:
    """One stored message: ``topic``, wire ``payload``, receive time (ns), file offset."""

    topic: bytes
    payload: bytes
    recv_time_ns: int
    offset: int


@dataclass
class RecordingScan:
    """What a read found: counts, where the good data ends, what was wrong after it."""

    records: int = 0
    good_end: int = len(HEADER)  # byte offset just after the last complete record
    file_size: int = 0
    corrupt: int = 0  # complete records whose CRC or framing failed (skipped)
    torn_bytes: int = 0  # bytes after the last complete record (a torn write)
    stopped: str | None = None  # why reading stopped before the end, if it did

    @property
    def complete(self) -> bool:
        return self.torn_bytes == 0 and self.stopped is None


def _check_header(path: Path, head: bytes) -> None:
    if len(head) < len(HEADER) or head[: len(MAGIC)] != MAGIC:
        raise MotionFileError(path, f"not a .sfrec recording: starts with {head[:8]!r}, expected {HEADER!r}")
    (version,) = struct.unpack("<H", head[len(MAGIC): len(HEADER)])
    if version > FORMAT_VERSION:
        raise MotionFileError(path, f"recording format version {version} is newer than supported {FORMAT_VERSION}")


def _scan(path: Path, scan: RecordingScan) -> Iterator[Record]:
    data = path.read_bytes()
    scan.file_size = len(data)
    _check_header(path, data[: len(HEADER)])
    pos = len(HEADER)
    n_data = len(data)
    while pos < n_data:
        if pos + _REC_HEAD.size > n_data:
            break  # torn record header
        length, crc = _REC_HEAD.unpack_from(data, pos)
        if length == 0 or length > MAX_RECORD_BYTES:
            scan.stopped = f"record at byte {pos} declares {length} bytes (limit {MAX_RECORD_BYTES}): cannot frame the rest"
            break
        start = pos + _REC_HEAD.size
        end = start + length
        if end > n_data:
            break  # torn body
        body = data[start:end]
        pos = end
        scan.good_end = end
        if zlib.crc32(body) != crc:
            scan.corrupt += 1
            continue
        try:
            topic, payload, t_recv = msgpack.unpackb(body, raw=False)
            topic, payload, t_recv = bytes(topic), bytes(payload), int(t_recv)
        except Exception:
            scan.corrupt += 1
            continue
        scan.records += 1
        yield Record(topic, payload, t_recv, start - _REC_HEAD.size)
    scan.torn_bytes = 0 if scan.stopped else n_data - scan.good_end


def iter_records(path: str | Path, scan: RecordingScan | None = None) -> Iterator[Record]:
    """Yield every complete, CRC-valid record in file order (stops at a torn tail).

    Pass a :class:`RecordingScan` to learn afterwards what was skipped or torn.
    """
    return _scan(Path(path), scan if scan is not None else RecordingScan())


def scan_recording(path: str | Path) -> RecordingScan:
    """Walk the file and report records, corrupt records and torn bytes."""
    scan = RecordingScan()
    for _ in _scan(Path(path), scan):
        pass
    return scan


class RecordingWriter:
    """Append wire messages to a ``.sfrec`` file, one ``write(2)`` per record.

    ``append=False`` (default) creates the file (an existing file is an error unless
    ``overwrite=True``); ``append=True`` continues an existing recording after
    cutting off a torn tail. ``fsync_interval_s``: fsync at most this often (0 = after
    every record); close() always fsyncs.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        append: bool = False,
        overwrite: bool = False,
        fsync_interval_s: float = 1.0,
    ) -> None:
        self.path = Path(path)
        self.fsync_interval_s = float(fsync_interval_s)
        self.records = 0
        self.bytes_written = 0
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT
        if append and self.path.exists() and self.path.stat().st_size > 0:
            scan = scan_recording(self.path)
            if scan.stopped:
                raise MotionFileError(self.path, f"cannot append: {scan.stopped}")
            if scan.torn_bytes:
                os.truncate(self.path, scan.good_end)  # drop the torn last record
            self._fd = os.open(self.path, flags)
        else:
            if not append and not overwrite:
                flags |= os.O_EXCL
            elif not append:
                flags |= os.O_TRUNC
            self._fd = os.open(self.path, flags, 0o644)
            self._write_all(HEADER)
            os.fsync(self._fd)
        self._last_sync = time.monotonic()

    def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]

    def write(self, topic: bytes, payload: bytes, recv_time_ns: int | None = None) -> None:
        """Append one message; when this returns the record survives a killed process."""
        if self._fd < 0:
            raise ValueError(f"{self.path}: recording is closed")
        body = msgpack.packb(
            [bytes(topic), bytes(payload), int(time.time_ns() if recv_time_ns is None else recv_time_ns)],
            use_bin_type=True,
        )
        self._write_all(_REC_HEAD.pack(len(body), zlib.crc32(body)) + body)
        self.records += 1
        self.bytes_written += _REC_HEAD.size + len(body)
        if self.fsync_interval_s <= 0 or time.monotonic() - self._last_sync >= self.fsync_interval_s:
            self.sync()

    def write_skeleton(self, stream_id: str, skeleton: Skeleton, rate_hz: float, *, recv_time_ns: int | None = None) -> None:
        payload = encode_skeleton_message(skeleton, rate_hz, stream_id, publish_time_ns=0)
        self.write(topic_for("meta", stream_id), payload, recv_time_ns)

    def write_frame(self, kind: str, frame: SkeletonFrame, *, recv_time_ns: int | None = None) -> None:
        self.write(topic_for(kind, frame.stream_id), encode_frame(frame), recv_time_ns)

    def sync(self) -> None:
        """fsync now (data and size reach the disk)."""
        if self._fd >= 0:
            os.fsync(self._fd)
            self._last_sync = time.monotonic()

    def close(self) -> None:
        if self._fd >= 0:
            try:
                os.fsync(self._fd)
            finally:
                os.close(self._fd)
                self._fd = -1

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class RecordingContents:
    """Decoded contents of a recording (see :func:`read_recording_frames`)."""

    frames: list[SkeletonFrame]
    kinds: list[str]  # topic kind of each frame ('raw', 'live', 'clean')
    recv_time_ns: list[int]
    skeletons: dict[str, SkeletonMessage]  # stream -> latest skeleton message
    scan: RecordingScan
    skipped: Counter = field(default_factory=Counter)  # undecodable payloads by reason

    def meta(self) -> dict:
        return {
            "kinds": self.kinds,
            "recv_time_ns": self.recv_time_ns,
            "skeletons": self.skeletons,
            "records": self.scan.records,
            "corrupt_records": self.scan.corrupt,
            "torn_bytes": self.scan.torn_bytes,
            "stopped": self.scan.stopped,
            "skipped": dict(self.skipped),
        }


def read_recording_contents(path: str | Path) -> RecordingContents:
    """Decode every message of a recording; bad payloads are counted, not raised."""
    scan = RecordingScan()
    frames: list[SkeletonFrame] = []
    kinds: list[str] = []
    recv: list[int] = []
    skeletons: dict[str, SkeletonMessage] = {}
    known: dict[str, Skeleton] = {}
    skipped: Counter = Counter()
    records = list(_scan(Path(path), scan))
    # Skeleton messages first: a recorder that joined mid-stream may have stored frames
    # before the stream's next skeleton message; they decode all the same.
    for rec in records:
        if rec.topic.startswith(b"sf/meta/"):
            try:
                msg = decode_message(rec.payload)
            except WireError:
                continue  # counted in the main pass
            if isinstance(msg, SkeletonMessage):
                known[msg.skeleton.name] = msg.skeleton
    for rec in records:
        try:
            kind, stream = parse_topic(rec.topic)
            msg = decode_message(rec.payload, known)
        except WireError as exc:
            skipped[exc.reason] += 1
            continue
        if isinstance(msg, SkeletonMessage):
            skeletons[msg.stream_id] = msg
        elif kind != "meta":
            frames.append(msg)
            kinds.append(kind)
            recv.append(rec.recv_time_ns)
    return RecordingContents(frames, kinds, recv, skeletons, scan, skipped)


def read_recording_frames(path: str | Path) -> tuple[list[SkeletonFrame], dict]:
    """Every frame of a recording in file order, plus metadata.

    ``meta``: ``kinds`` (topic kind per frame), ``recv_time_ns`` (per frame),
    ``skeletons`` (stream -> :class:`SkeletonMessage`), ``records``,
    ``corrupt_records``, ``torn_bytes``, ``stopped``, ``skipped`` (by reason).
    """
    contents = read_recording_contents(path)
    return contents.frames, contents.meta()


_KIND_PREFERENCE = ("clean", "raw", "live")


def read_motion_sfrec(
    path: str | Path,
    *,
    stream: str | None = None,
    kind: str | None = None,
    body: int | None = None,
) -> Motion:
    """One body of one stream of a recording as a :class:`Motion`.

    ``stream``: default the first frame's stream. ``kind``: default ``clean`` if the
    stream has it, else ``raw``, else ``live``. ``body``: default the body id present
    in the most frames. Frames where that body is absent are missing (NaN, confidence
    0). Positions pass through float32 on the wire (about 1e-7 m at 1 m). Timestamps
    are the sensor times in seconds; ``rate_hz`` comes from the skeleton message
    (else the median frame interval). ``meta`` holds ``seq``, ``filled``, ``stream``,
    ``kind``, ``body_id``.
    """
    path = Path(path)
    c = read_recording_contents(path)
    if not c.frames:
        skipped = ", ".join(f"{n} {why}" for why, n in c.skipped.items()) or "none"
        raise MotionFileError(path, f"no frames in the recording ({c.scan.records} records; skipped: {skipped})")
    streams = [f.stream_id for f in c.frames]
    stream = stream or streams[0]
    kinds_here = {k for f, k in zip(c.frames, c.kinds) if f.stream_id == stream}
    if not kinds_here:
        raise MotionFileError(path, f"no frames of stream {stream!r}; streams: {sorted(set(streams))}")
    if kind is None:
        kind = next(k for k in _KIND_PREFERENCE if k in kinds_here)
    elif kind not in kinds_here:
        raise MotionFileError(path, f"stream {stream!r} has no {kind!r} frames; it has {sorted(kinds_here)}")
    selected = [f for f, k in zip(c.frames, c.kinds) if f.stream_id == stream and k == kind]
    # one frame per seq, in sensor-time order
    by_seq: dict[int, SkeletonFrame] = {}
    for f in selected:
        by_seq.setdefault(f.seq, f)
    frames = sorted(by_seq.values(), key=lambda f: (f.sensor_time_ns, f.seq))
    counts = Counter(b.body_id for f in frames for b in f.bodies)
    if body is None:
        if not counts:
            raise MotionFileError(path, f"stream {stream!r} ({kind}) has frames but no bodies")
        body = min(counts, key=lambda b: (-counts[b], b))
    elif body not in counts:
        raise MotionFileError(path, f"stream {stream!r} ({kind}) has no body {body}; bodies: {sorted(counts)}")
    info = c.skeletons.get(stream)
    name = frames[0].skeleton
    if info is not None and info.skeleton.name == name:
        skeleton = info.skeleton
    else:
        try:
            skeleton = get_skeleton(name)
        except KeyError as exc:
            raise MotionFileError(path, str(exc)) from None
    T, J = len(frames), skeleton.n_joints
    positions = np.full((T, J, 3), np.nan)
    confidence = np.zeros((T, J))
    recovered = np.zeros((T, J), bool)
    has_rec = False
    for t, f in enumerate(frames):
        for b in f.bodies:
            if b.body_id == body:
                positions[t] = b.positions
                confidence[t] = b.confidence
                if b.recovered is not None:
                    recovered[t] = b.recovered
                    has_rec = True
                break
    timestamps = np.array([f.sensor_time_ns for f in frames], dtype=np.float64) * 1e-9
    if info is not None:
        rate = info.rate_hz
    elif T > 1 and np.median(np.diff(timestamps)) > 0:
        rate = 1.0 / float(np.median(np.diff(timestamps)))
    else:
        rate = 30.0
    return Motion(
        positions, confidence, timestamps, rate, skeleton,
        recovered=recovered if has_rec else None,
        meta={
            "source": str(path),
            "stream": stream,
            "kind": kind,
            "body_id": body,
            "seq": np.array([f.seq for f in frames], dtype=np.int64),
            "filled": np.array([f.filled for f in frames], dtype=bool),
        },
    )


def read_recording(path: str | Path, **kwargs) -> Motion:
    """``streamfix.io.read_motion`` entry point for ``.sfrec``: see :func:`read_motion_sfrec`."""
    return read_motion_sfrec(path, **kwargs)


def write_motion_sfrec(
    motion: Motion,
    path: str | Path,
    *,
    stream_id: str = "motion",
    body_id: int = 0,
    kind: str | None = None,
    overwrite: bool = True,
) -> None:
    """Write a motion as a recording: its skeleton message, then one frame per sample.

    ``kind`` default: ``clean`` when the motion has a ``recovered`` mask, else ``raw``.
    Sequence numbers count from 0; sensor times are the timestamps in ns.
    """
    kind = kind or ("clean" if motion.recovered is not None else "raw")
    times = np.round(np.asarray(motion.timestamps, dtype=np.float64) * 1e9).astype(np.int64)
    with RecordingWriter(path, overwrite=overwrite, fsync_interval_s=3600.0) as w:
        w.write_skeleton(stream_id, motion.skeleton, motion.rate_hz, recv_time_ns=0)
        for t in range(motion.n_frames):
            rec = None if motion.recovered is None else motion.recovered[t]
            frame = SkeletonFrame(
                stream_id, t, int(times[t]), motion.skeleton.name,
                [BodyFrame(body_id, motion.positions[t], motion.confidence[t], rec)],
            )
            w.write_frame(kind, frame, recv_time_ns=0)


def write_recording(motion: Motion, path: str | Path, **kwargs) -> None:
    """``streamfix.io.write_motion`` entry point for ``.sfrec``: see :func:`write_motion_sfrec`."""
    write_motion_sfrec(motion, path, **kwargs)
