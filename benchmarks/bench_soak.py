"""Soak / overload benchmark: ``streamfix serve`` fed N bodies at k x real time for a long time.

A sender PUSHes Kinect v2 frames (bodies cut from the real recordings in
``../shared/data/kinect_v2``, offset in space) for S streams of at most 6 bodies each,
N bodies in all, at k x the 30 Hz sensor rate (frame i is due at ``i / (30 k)`` s; the
sensor clock says 30 Hz, so k > 1 is more data than a sensor makes: an overload). A
SUB in this process takes every ``live`` frame and, per stream, checks the wire
promises: within an epoch ``seq`` goes up by exactly 1; every input frame is either
delivered (a real live frame) or announced as shed (the ``dropped`` counts). Measured:

* live latency from the frame's send (its arrival at the service, to within loopback
  time) to its receipt here, p50/p99, after warm-up; and the service's own
  ``streamfix_live_latency_seconds`` (arrival -> publish) for comparison;
* the service's RSS every ``--sample`` seconds, and its growth after warm-up;
* shed (``streamfix_shed_frames_total``), publish drops, limit hits, failures,
  restarts, engine degradation, the backlog gauge.

Exit status 1 when RSS grows by more than 10 % after warm-up, when an input frame is
neither delivered nor counted (by the service's metrics and by the ``dropped`` counts on
the wire), or when a ``seq`` promise is broken. Results go to
``benchmarks/results/soak.json`` (and a table on stdout).

    python benchmarks/bench_soak.py                         # 10 minutes, 20 bodies at 5x
    python benchmarks/bench_soak.py --minutes 1 --bodies 20 --speed 5
    python benchmarks/bench_soak.py --minutes 180 --bodies 6 --speed 1   # hours
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import zmq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_service import bodies_source, free_port, metrics, wait_until_serving  # noqa: E402
from streamfix.frames import BodyFrame, SkeletonFrame  # noqa: E402
from streamfix.skeletons import KINECT_V2  # noqa: E402
from streamfix.transport.wire import decode_frame, encode_frame, encode_skeleton_message, topic_for  # noqa: E402

RATE_HZ = 30.0
MAX_BODIES_PER_STREAM = 6
RSS_GROWTH_LIMIT = 0.10
RESULTS = ROOT / "benchmarks" / "results"


def rss_mb(pid: int) -> float:
    """Resident set size of a process, MB (from /proc)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class Checker:
    """Per-stream wire checks on the live topic: seq by epoch, delivered and announced-shed counts."""

    def __init__(self) -> None:
        self.last: dict[str, tuple[int, int]] = {}
        self.real = defaultdict(int)
        self.dropped = defaultdict(int)
        self.filled = defaultdict(int)
        self.seq_errors: list[str] = []
        self.epochs = defaultdict(set)
        self.latency: list[tuple[float, float]] = []  # (send time s since start, latency s)

    def take(self, f: SkeletonFrame, now_ns: int, sent_ns: dict, t0_ns: int) -> None:
        prev = self.last.get(f.stream_id)
        if prev is not None and prev[0] == f.epoch and f.seq != prev[1] + 1:
            if len(self.seq_errors) < 20:
                self.seq_errors.append(f"{f.stream_id}: seq {f.seq} after {prev[1]} in epoch {f.epoch}")
        if prev is not None and f.epoch < prev[0]:
            self.seq_errors.append(f"{f.stream_id}: epoch went back {prev[0]} -> {f.epoch}")
        self.last[f.stream_id] = (f.epoch, f.seq)
        self.epochs[f.stream_id].add(f.epoch)
        self.dropped[f.stream_id] += f.dropped
        if f.filled:
            self.filled[f.stream_id] += 1
            return
        self.real[f.stream_id] += 1
        sent = sent_ns.get((f.stream_id, f.sensor_time_ns))
        if sent is not None:
            self.latency.append(((sent - t0_ns) / 1e9, (now_ns - sent) / 1e9))


def run(args: argparse.Namespace) -> dict:
    pos, conf = bodies_source()
    T = pos.shape[0]
    n_streams = max(1, -(-args.bodies // MAX_BODIES_PER_STREAM))
    per_stream = [args.bodies // n_streams + (1 if s < args.bodies % n_streams else 0) for s in range(n_streams)]
    streams = [f"soak{s}" for s in range(n_streams)]
    in_port, out_port, m_port = free_port(), free_port(), free_port()
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "streamfix", "serve", "--source", f"tcp://127.0.0.1:{in_port}",
           "--out", f"tcp://127.0.0.1:{out_port}", "--metrics-port", str(m_port), "--status-interval", "0",
           "--log-level", "ERROR", "--idle-timeout", "0", *args.serve_args]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=str(ROOT))
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    push = ctx.socket(zmq.PUSH)
    checker = Checker()
    sent_ns: dict[tuple[str, int], int] = {}
    rss: list[tuple[float, float]] = []
    done = threading.Event()
    try:
        wait_until_serving(proc, m_port)
        sub.setsockopt(zmq.RCVHWM, 0)
        sub.setsockopt(zmq.SUBSCRIBE, b"sf/live/")
        sub.connect(f"tcp://127.0.0.1:{out_port}")
        push.setsockopt(zmq.LINGER, 0)
        push.setsockopt(zmq.SNDHWM, 100_000)
        push.connect(f"tcp://127.0.0.1:{in_port}")
        time.sleep(0.5)  # the subscription propagates
        t0_ns = time.time_ns()

        def receive() -> None:
            poller = zmq.Poller()
            poller.register(sub, zmq.POLLIN)
            while not done.is_set():
                if not poller.poll(100):
                    continue
                while True:
                    try:
                        _, payload = sub.recv_multipart(zmq.NOBLOCK)
                    except zmq.Again:
                        break
                    checker.take(decode_frame(payload), time.time_ns(), sent_ns, t0_ns)

        rx = threading.Thread(target=receive, daemon=True)
        rx.start()
        for sid in streams:
            push.send_multipart([topic_for("meta", sid), encode_skeleton_message(KINECT_V2, RATE_HZ, sid)])
        t_start = time.monotonic()
        duration = args.minutes * 60.0
        period_ns = int(1e9 / RATE_HZ)
        send_rate = RATE_HZ * args.speed
        next_sample = t_start
        i = 0
        sent = 0
        while True:
            now = time.monotonic()
            if now >= next_sample:
                rss.append((now - t_start, rss_mb(proc.pid)))
                next_sample += args.sample
            if now - t_start >= duration:
                break
            due = t_start + i / send_rate
            if due > now:
                time.sleep(min(due - now, 0.05))
                continue
            for s, sid in enumerate(streams):
                bodies = []
                for b in range(per_stream[s]):
                    k = (i + 37 * b + 101 * s) % T
                    p = pos[k].copy()
                    p[:, 0] += 0.8 * b
                    bodies.append(BodyFrame(b, p, conf[k]))
                t_sensor = i * period_ns
                payload = encode_frame(SkeletonFrame(sid, i, t_sensor, KINECT_V2.name, bodies))
                sent_ns[(sid, t_sensor)] = time.time_ns()
                push.send_multipart([topic_for("raw", sid), payload])
                sent += 1
            i += 1
        elapsed = time.monotonic() - t_start
        time.sleep(1.5)  # what is in flight arrives (live output is immediate)
        m_before = metrics(m_port)
        proc.terminate()
        rc = proc.wait(timeout=120)
        time.sleep(0.5)
        done.set()
        rx.join(timeout=2)
        stderr = proc.stderr.read().decode(errors="replace")
    finally:
        done.set()
        if proc.poll() is None:
            proc.kill()
        sub.close(linger=0)
        push.close(linger=0)
        ctx.term()

    def total(prefix: str) -> float:
        return sum(v for k, v in m_before.items() if k.startswith(prefix + "{") or k == prefix)

    lat = np.array([l for t, l in checker.latency if t >= args.warmup])
    warm = [r for t, r in rss if t >= args.warmup]
    growth = (max(warm[1:]) - warm[0]) / warm[0] if len(warm) > 1 else 0.0
    delivered = sum(checker.real.values())
    announced = sum(checker.dropped.values())
    frames_in = total("streamfix_frames_in_total")
    shed = total("streamfix_shed_frames_total")
    limits = total("streamfix_limit_hits_total")
    malformed = total("streamfix_malformed_total")
    pub_drops = total("streamfix_publish_drops_total")
    service_accounted = frames_in + shed + limits + malformed
    wire_accounted = delivered + announced
    return {
        "bodies": args.bodies, "streams": n_streams, "speed": args.speed, "minutes": args.minutes,
        "seconds_run": round(elapsed, 1), "frames_sent": sent, "send_rate_hz": round(sent / elapsed, 1),
        "serve_exit": rc,
        "delivered_live": delivered, "announced_dropped": announced, "filled": sum(checker.filled.values()),
        "service_frames_in": frames_in, "service_shed": shed, "service_limit_hits": limits,
        "service_malformed": malformed, "publish_drops": pub_drops,
        "uncounted_service": sent - service_accounted,
        "unannounced_on_wire": sent - wire_accounted,  # shed at shutdown (the backlog keeps a stream's newest frame)
        "seq_errors": checker.seq_errors, "epochs": {k: len(v) for k, v in checker.epochs.items()},
        "live_p50_ms": float(np.percentile(lat, 50) * 1e3) if lat.size else None,
        "live_p99_ms": float(np.percentile(lat, 99) * 1e3) if lat.size else None,
        "service_live_p99_bucket_ok": _share_le(m_before, "streamfix_live_latency_seconds", "0.1"),
        "degraded": m_before.get("streamfix_degraded", 0.0), "backlog_frames_end": m_before.get(
            "streamfix_input_backlog_frames", 0.0),
        "failures": total("streamfix_stream_failures_total"), "restarts": total("streamfix_stream_restarts_total"),
        "rss_mb": [(round(t, 1), round(r, 1)) for t, r in rss],
        "rss_growth_after_warmup": round(growth, 4),
        "shutdown_log": [ln for ln in stderr.splitlines() if "shutdown" in ln][-5:],
        "load_average": os.getloadavg()[0],
    }


def _share_le(m: dict, name: str, bound: str) -> float | None:
    count = m.get(f"{name}_count", 0.0)
    return m.get(f'{name}_bucket{{le="{bound}"}}', 0.0) / count if count else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="how long to feed the service (default 10)")
    ap.add_argument("--bodies", type=int, default=20, help="bodies in all (streams of at most 6; default 20)")
    ap.add_argument("--speed", type=float, default=5.0, help="k: frames sent at k x 30 Hz (default 5)")
    ap.add_argument("--warmup", type=float, default=20.0, help="seconds excluded from latency and RSS growth")
    ap.add_argument("--sample", type=float, default=5.0, help="seconds between RSS samples")
    ap.add_argument("--out", default=str(RESULTS / "soak.json"), help="results file (JSON)")
    ap.add_argument("serve_args", nargs="*", help="extra `streamfix serve` arguments (after --)")
    args = ap.parse_args()
    r = run(args)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(r, indent=1) + "\n")
    print(f"streamfix serve soak: {r['bodies']} bodies in {r['streams']} streams at {r['speed']:g}x "
          f"({r['send_rate_hz']} frames/s sent) for {r['seconds_run']} s; load average {r['load_average']:.1f}")
    for key in ("frames_sent", "delivered_live", "announced_dropped", "filled", "service_frames_in", "service_shed",
                "service_limit_hits", "publish_drops", "uncounted_service", "unannounced_on_wire", "live_p50_ms",
                "live_p99_ms", "service_live_p99_bucket_ok", "degraded", "failures", "restarts",
                "rss_growth_after_warmup", "serve_exit"):
        print(f"  {key:<28} {r[key]}")
    print(f"  RSS MB (t s, MB): {r['rss_mb'][:3]} ... {r['rss_mb'][-3:]}")
    failures = []
    if r["rss_growth_after_warmup"] > RSS_GROWTH_LIMIT:
        failures.append(f"RSS grew {r['rss_growth_after_warmup']:.1%} after warm-up (limit 10 %)")
    if r["uncounted_service"] != 0:
        failures.append(f"{r['uncounted_service']} input frames neither handled nor counted by the service")
    if r["publish_drops"] == 0 and (r["delivered_live"] != r["service_frames_in"]
                                    or r["announced_dropped"] > r["service_shed"]):
        failures.append(f"subscriber and metrics disagree: {r['delivered_live']} live frames received, "
                        f"{r['service_frames_in']} handled; {r['announced_dropped']} announced dropped, "
                        f"{r['service_shed']} shed")
    if r["seq_errors"]:
        failures.append(f"seq promises broken: {r['seq_errors'][:3]}")
    if r["serve_exit"] != 0:
        failures.append(f"serve exited {r['serve_exit']}")
    for f in failures:
        print("MISSED:", f)
    print(f"results: {args.out}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
