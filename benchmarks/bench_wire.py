"""Wire codec speed: encoding is on the live path (one encode per frame per output topic).

Target: ``streamfix.transport.wire.encode_frame`` of a 25-joint Kinect v2 frame with
one body (cleaned output, with the ``rec`` blob) well under 100 us; decode is timed too
(subscribers, the service's input). Each case is the best of N batches in CPU time of
this process (``time.process_time``), so other tenants of a busy machine do not count.

Baselines measured in the same run: ``msgpack.packb`` of the already-built message map
(the floor: what msgpack alone costs) and ``json.dumps`` of the same frame with joints
as nested lists (what a naive text protocol would cost). The table reports each
codec time and its ratio to both.

Exit status 1 when encode of the one-body frame is not under 100 us.
Run: ``python benchmarks/bench_wire.py [--repeats N]``
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import msgpack
import numpy as np

from streamfix.frames import BodyFrame, SkeletonFrame
from streamfix.skeletons import KINECT_V2
from streamfix.transport.wire import decode_frame, encode_frame

TARGET_ENCODE_US = 100.0


def _frame(n_bodies: int) -> SkeletonFrame:
    rng = np.random.default_rng(n_bodies)
    J = KINECT_V2.n_joints
    bodies = []
    for b in range(n_bodies):
        pos = rng.normal(size=(J, 3))
        pos[3] = np.nan
        bodies.append(BodyFrame(b, pos, np.ones(J), rng.random(J) < 0.1))
    return SkeletonFrame("kinect0", 123, 4_000_000_000, "kinect_v2", bodies, publish_time_ns=1)


def _best_us(fn, repeats: int, batch: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        for _ in range(batch):
            fn()
        best = min(best, (time.process_time() - t0) / batch)
    return best * 1e6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batch", type=int, default=2000)
    args = parser.parse_args(argv)

    rows = []
    for n_bodies in (1, 6):
        frame = _frame(n_bodies)
        payload = encode_frame(frame)
        prebuilt = msgpack.unpackb(payload, raw=False)
        as_json = {
            **{k: v for k, v in prebuilt.items() if k != "bodies"},
            "bodies": [{"id": b.body_id, "joints": b.positions.tolist(), "conf": b.confidence.tolist(),
                        "rec": b.recovered.tolist()} for b in frame.bodies],
        }
        floor = _best_us(lambda: msgpack.packb(prebuilt, use_bin_type=True), args.repeats, args.batch)
        naive = _best_us(lambda: json.dumps(as_json), args.repeats, max(1, args.batch // 10))
        enc = _best_us(lambda: encode_frame(frame), args.repeats, args.batch)
        dec = _best_us(lambda: decode_frame(payload), args.repeats, args.batch)
        rows.append((n_bodies, len(payload), enc, dec, floor, naive))

    print(f"{'bodies':>6} {'bytes':>6} {'encode us':>10} {'decode us':>10} {'packb floor us':>15} "
          f"{'json us':>8} {'enc/floor':>10} {'enc/json':>9}")
    for n, size, enc, dec, floor, naive in rows:
        print(f"{n:>6} {size:>6} {enc:>10.2f} {dec:>10.2f} {floor:>15.2f} {naive:>8.2f} "
              f"{enc / floor:>10.2f} {enc / naive:>9.3f}")
    enc_one = rows[0][2]
    ok = enc_one < TARGET_ENCODE_US
    print(f"target: encode of a one-body 25-joint frame < {TARGET_ENCODE_US:g} us: "
          f"{enc_one:.2f} us -> {'met' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
