"""Harness for the end-to-end tests: real ``streamfix serve`` / ``replay`` processes on loopback.

Every child runs with a bounded timeout and is killed in a ``finally``; ports are picked
free at run time; the service's stderr goes to a file (no pipe to fill up).
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import zmq

from streamfix.service.metrics import parse_prometheus_text
from streamfix.transport.zmq_io import Subscriber

PROJECT_ROOT = Path(__file__).resolve().parents[1]


def child_env() -> dict:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = str(PROJECT_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _ephemeral_range() -> tuple[int, int]:
    try:
        lo, hi = (int(v) for v in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
        return lo, hi
    except (OSError, ValueError):
        return 32768, 60999  # Linux's default


_PORTS = iter(())


def free_port() -> int:
    """A loopback TCP port free now, below the kernel's ephemeral range: a port the OS hands
    out for binding to 0 can be taken again as the local end of any outgoing connection
    (a ZeroMQ connect) before the child binds it ("Address already in use" at random)."""
    global _PORTS
    lo = min(_ephemeral_range()[0], 32768)
    start = 20000 + (os.getpid() * 7919) % max(1, lo - 20000 - 1)
    for _ in range(2):
        for port in _PORTS:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
                return port
        _PORTS = iter(list(range(start, lo)) + list(range(20000, start)))
    raise RuntimeError(f"no free loopback port in 20000..{lo - 1}")


def fetch_metrics(port: int, timeout: float = 2.0) -> dict[str, float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=timeout) as resp:
        return parse_prometheus_text(resp.read().decode())


def kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass


class ServeProcess:
    """A running ``python -m streamfix serve`` with a zmq source, PUB output and metrics."""

    def __init__(self, tmp_path: Path, *extra: str, source: str | None = None, name: str = "serve") -> None:
        self.in_port, self.out_port, self.metrics_port = free_port(), free_port(), free_port()
        self.source = source or f"tcp://127.0.0.1:{self.in_port}"
        self.out = f"tcp://127.0.0.1:{self.out_port}"
        self.stderr_path = tmp_path / f"{name}.stderr"
        self._stderr = open(self.stderr_path, "wb")
        # exact-delivery tests feed bursts (replay --speed 0) on a loaded machine: back-pressure, not shedding
        policy = () if "--overload" in extra else ("--overload", "block")
        cmd = [
            sys.executable, "-m", "streamfix", "serve",
            "--source", self.source, "--out", self.out,
            "--metrics-port", str(self.metrics_port), "--status-interval", "0", *policy, *extra,
        ]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=self._stderr, env=child_env(),
                                     cwd=str(PROJECT_ROOT))

    @property
    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def wait_ready(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise AssertionError(f"serve exited early ({self.proc.returncode}):\n{self.stderr}")
            try:
                fetch_metrics(self.metrics_port, timeout=0.5)
                return
            except OSError:
                time.sleep(0.1)
        raise AssertionError(f"serve not ready within {timeout} s:\n{self.stderr}")

    def metrics(self) -> dict[str, float]:
        return fetch_metrics(self.metrics_port)

    def terminate(self, timeout: float = 30.0) -> int:
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=timeout)

    def close(self) -> None:
        kill(self.proc)
        self._stderr.close()


@contextmanager
def serve(tmp_path: Path, *extra: str, source: str | None = None, name: str = "serve", ready: bool = True):
    sp = ServeProcess(tmp_path, *extra, source=source, name=name)
    try:
        if ready:
            sp.wait_ready()
        yield sp
    finally:
        sp.close()


def connected_subscriber(endpoint: str, prefixes=(b"sf/",), timeout: float = 10.0, **kw) -> Subscriber:
    """A streamfix Subscriber whose connection to the PUB is up (its subscription then follows)."""
    sub = Subscriber(endpoint, prefixes, rcvhwm=0, **kw)
    sub.socket.disconnect(endpoint)  # reconnect under a monitor to see the handshake
    connect_and_wait(sub.socket, endpoint, timeout)
    return sub


def connect_and_wait(sock: zmq.Socket, endpoint: str, timeout: float = 10.0) -> None:
    """Connect and block until the handshake with the peer has completed, then let subscriptions land."""
    mon = sock.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED)
    try:
        sock.connect(endpoint)
        if not mon.poll(int(timeout * 1000)):
            raise AssertionError(f"no ZeroMQ handshake with {endpoint} within {timeout} s")
        mon.recv_multipart()
    finally:
        sock.disable_monitor()
        mon.close(linger=0)
    time.sleep(0.2)  # the SUBSCRIBE commands travel right after the handshake


def run_replay(path: str | Path, to: str, *extra: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "streamfix", "replay", str(path), "--to", to, *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=child_env(), cwd=str(PROJECT_ROOT))


def test_free_ports_are_distinct_and_bindable():
    ports = {free_port() for _ in range(3)}
    assert len(ports) == 3
    with socket.socket() as s:
        s.bind(("127.0.0.1", ports.pop()))


def collect_until(done, collect, progress, *, stall_s: float = 20.0, max_s: float = 240.0) -> None:
    """Call ``collect()`` until ``done()``; give up after ``stall_s`` without ``progress()``
    changing (the service stopped producing) or ``max_s`` in all. A busy machine slows
    the service down but does not stall it, so the bound is on silence, not on speed."""
    start = last_change = time.monotonic()
    seen = progress()
    while not done():
        now = time.monotonic()
        if now - last_change > stall_s or now - start > max_s:
            return
        collect()
        if progress() != seen:
            seen, last_change = progress(), time.monotonic()


def wait_metric(sp, key: str, at_least: float, timeout: float = 30.0) -> dict:
    """Poll a running serve's metrics until ``key`` reaches ``at_least`` or ``timeout`` s pass (serve must stay up)."""
    deadline = time.monotonic() + timeout
    while True:
        m = sp.metrics()
        if m.get(key, 0.0) >= at_least or time.monotonic() > deadline:
            return m
        assert sp.proc.poll() is None, f"serve died:\n{sp.stderr[-3000:]}"
        time.sleep(0.1)
