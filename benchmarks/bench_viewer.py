"""Viewer responsiveness: 4 bodies at 30 Hz for 60 s through ``serve --view`` into headless Chromium.

Set-up, all real: four real Kinect v2 takes side by side as one 4-body stream
(:func:`streamfix.viewer.crowd.write_crowd_recording`), played in a loop by
``streamfix replay`` into ``streamfix serve --view``; a headless Chromium loads the
viewer. Every second the page's own account (``window.sfStatus``, read over the DevTools
protocol) and the server's ``/status`` are sampled.

Measured: frames the page drew per second (its own counter), the records it received per
second, the age of the clean frame on screen (wall clock now minus the service's publish
time of that frame: wire, bridge and page, not the lookahead; the oldest in each second), the page's draw cost, and the bridge: its
per-page queue (records pending, at most one per stream), unacknowledged messages, raw
frames held for pairing, and records dropped because newer ones pushed them out; the
page's own skips (records it had but did not draw because a later one was already due).

Targets (exit 1 when missed): the page's frame counter advances in every one-second
window (never frozen); it draws >= 15 frames/s on average; the bridge's queue never
exceeds the board's 8 records for the one stream and at most 2 messages are
unacknowledged; the clean frame on screen is never more than 1 s older than its
publication by the service (no backlog), and that age in the last 10 s is no worse
than in the first 10 s + 200 ms.
Results: ``benchmarks/results/bench_viewer.json``.

    python benchmarks/bench_viewer.py [--seconds 60] [--bodies 4]
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from streamfix.viewer.crowd import write_crowd_recording  # noqa: E402
from streamfix.viewer.headless import HeadlessChromium  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "kinect_v2"
RESULTS = ROOT / "benchmarks" / "results" / "bench_viewer.json"
MIN_FPS = 15.0
MAX_QUEUE = 8            # one stream: at most the board's `keep` (8) newest records pending
MAX_UNACKED = 2
MAX_AGE_MS = 1000        # wall clock from the service's publish of a clean frame to the page showing it
AGE_GROWTH_MS = 200


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=5) as r:
        return json.load(r)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--bodies", type=int, default=4)
    args = ap.parse_args()
    sources = sorted(DATA.glob("*.csv"))[: args.bodies]
    if len(sources) < args.bodies:
        print(f"bench_viewer: need {args.bodies} Kinect takes in {DATA}, found {len(sources)}", file=sys.stderr)
        return 2
    env = {"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    import os

    env = {**os.environ, **env}
    procs: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory() as tmp:
        crowd = Path(tmp) / "crowd.sfrec"
        write_crowd_recording(sources, crowd)
        src, out = f"tcp://127.0.0.1:{_free_port()}", f"tcp://127.0.0.1:{_free_port()}"
        err_path = Path(tmp) / "serve.stderr"
        err = open(err_path, "wb")
        try:
            procs.append(subprocess.Popen([sys.executable, "-m", "streamfix", "serve", "--source", src, "--out", out,
                                           "--view", "0", "--status-interval", "0", "--idle-timeout", "0"],
                                          env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err))
            url = None
            deadline = time.monotonic() + 60
            while url is None and time.monotonic() < deadline:
                m = re.search(r"open (http://127\.0\.0\.1:\d+/)", err_path.read_text(errors="replace"))
                url = m.group(1) if m else None
                time.sleep(0.1)
            if url is None:
                print(f"bench_viewer: serve --view printed no address:\n{err_path.read_text()}", file=sys.stderr)
                return 2
            procs.append(subprocess.Popen([sys.executable, "-m", "streamfix", "replay", str(crowd), "--to", src,
                                           "--loop", "--quiet"], env=env, cwd=ROOT,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            with HeadlessChromium() as browser:
                browser.goto(url)
                browser.wait_for(f"window.sfStatus && sfStatus.bodies === {args.bodies} && sfStatus.framesDrawn > 3", 60)
                time.sleep(2.0)  # warm-up: the service's first windows, the page's first layouts
                samples = []
                t_end = time.monotonic() + args.seconds
                while time.monotonic() < t_end:
                    time.sleep(1.0)
                    page = browser.evaluate("JSON.parse(JSON.stringify(window.sfStatus))")
                    samples.append((time.monotonic(), page, _get(url + "status")))
                RESULTS.parent.mkdir(parents=True, exist_ok=True)
                browser.screenshot(RESULTS.with_suffix(".png"))
        finally:
            for p in reversed(procs):
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
            err.close()

    t = np.array([s[0] for s in samples])
    drawn = np.array([s[1]["framesDrawn"] for s in samples], dtype=float)
    records = np.array([s[1]["records"] for s in samples], dtype=float)
    age = np.array([s[1]["maxAgeMs"] or 0 for s in samples], dtype=float)
    draw_ms = np.array([s[1]["drawMs"] for s in samples], dtype=float)
    clients = [s[2]["clients"][0] for s in samples if s[2]["clients"]]
    queue = max(c["max_queue"] for c in clients)
    unacked = max(c["unacked"] for c in clients)
    held = max(s[2]["held"] for s in samples)
    dropped, taken = clients[-1]["dropped"], clients[-1]["taken"]
    skipped = samples[-1][1]["skipped"] - samples[0][1]["skipped"]
    per_s = np.diff(drawn) / np.diff(t)
    rec_per_s = np.diff(records) / np.diff(t)
    n10 = max(1, int(10 / max(np.median(np.diff(t)), 1e-3)))
    first_age, last_age = float(np.median(age[:n10])), float(np.median(age[-n10:]))
    result = {
        "seconds": float(t[-1] - t[0]), "bodies": args.bodies, "rate_hz": 30,
        "page_fps_mean": float(per_s.mean()), "page_fps_min_1s": float(per_s.min()),
        "records_per_s_mean": float(rec_per_s.mean()),
        "frozen_windows": int((per_s <= 0).sum()),
        "age_ms_median_first10s": first_age, "age_ms_median_last10s": last_age, "age_ms_max": float(age.max()),
        "draw_ms_mean": float(draw_ms.mean()), "draw_ms_max": float(draw_ms.max()),
        "bridge_max_queue": int(queue), "max_unacked": int(unacked), "held_max": int(held),
        "records_taken": int(taken), "records_dropped": int(dropped),
        "dropped_share": float(dropped / max(1, dropped + taken)),
        "page_skipped": int(skipped),
    }
    checks = {
        f"page frame counter advances every second (frozen windows = 0)": result["frozen_windows"] == 0,
        f"page draws >= {MIN_FPS:g} frames/s on average": result["page_fps_mean"] >= MIN_FPS,
        f"bridge queue <= {MAX_QUEUE} records (one stream)": queue <= MAX_QUEUE,
        f"unacknowledged messages <= {MAX_UNACKED}": unacked <= MAX_UNACKED,
        f"clean frame on screen never > {MAX_AGE_MS} ms after the service published it":
            result["age_ms_max"] <= MAX_AGE_MS,
        f"age does not grow (last 10 s <= first 10 s + {AGE_GROWTH_MS} ms)": last_age <= first_age + AGE_GROWTH_MS,
    }
    result["checks"] = {k: bool(v) for k, v in checks.items()}
    RESULTS.write_text(json.dumps(result, indent=1) + "\n")
    print(f"bench_viewer: {args.bodies} bodies x 30 Hz for {result['seconds']:.0f} s, serve --view -> headless Chromium")
    for k in ("page_fps_mean", "page_fps_min_1s", "records_per_s_mean", "draw_ms_mean", "draw_ms_max",
              "age_ms_median_first10s", "age_ms_median_last10s", "age_ms_max", "bridge_max_queue", "max_unacked",
              "held_max", "records_dropped", "dropped_share", "page_skipped"):
        v = result[k]
        print(f"  {k:<26} {v:10.3f}" if isinstance(v, float) else f"  {k:<26} {v:10d}")
    for k, ok in checks.items():
        print(f"  [{'ok' if ok else 'MISSED'}] {k}")
    print(f"  results: {RESULTS.relative_to(ROOT)}")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
