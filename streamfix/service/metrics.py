"""Service metrics: counters, gauges and histograms in the Prometheus text format.

A tiny, dependency-free subset of the Prometheus client model, enough for
``streamfix serve``: metric families with optional labels, rendered in the text
exposition format 0.0.4 and served over HTTP (``GET /metrics``) from a daemon
thread bound to 127.0.0.1 by default. Updates happen on the service's main thread
and reads on the HTTP thread, so every family guards its values with one lock.

Units: latencies are observed in **seconds** (the Prometheus convention), names end
in ``_seconds``; counters end in ``_total``.
"""
from __future__ import annotations

import bisect
import math
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

__all__ = [
    "Counter",
    "Gauge",
    "Histogram",
    "Registry",
    "MetricsServer",
    "LATENCY_BUCKETS_S",
]

# Bucket upper bounds (s): dense below 2 ms for the live path, up to 10 s for clean end-to-end.
LATENCY_BUCKETS_S: tuple[float, ...] = (
    0.00025, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0,
)


def _escape(value: str) -> str:
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _fmt(value: float) -> str:
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    if math.isnan(value):
        return "NaN"
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value))


def _labels(names: tuple[str, ...], values: tuple[str, ...], extra: str = "") -> str:
    parts = [f'{n}="{_escape(v)}"' for n, v in zip(names, values)]
    if extra:
        parts.append(extra)
    return "{" + ",".join(parts) + "}" if parts else ""


class _Family:
    kind = "untyped"

    def __init__(self, name: str, help_text: str, labelnames: tuple[str, ...] = ()) -> None:
        self.name = name
        self.help = help_text
        self.labelnames = tuple(labelnames)
        self._lock = threading.Lock()

    def _key(self, labels: dict[str, str] | None) -> tuple[str, ...]:
        labels = labels or {}
        if set(labels) != set(self.labelnames):
            raise ValueError(
                f"metric {self.name} takes labels {list(self.labelnames)}, got {sorted(labels)}"
            )
        return tuple(str(labels[n]) for n in self.labelnames)

    def header(self) -> list[str]:
        return [f"# HELP {self.name} {self.help}", f"# TYPE {self.name} {self.kind}"]


class Counter(_Family):
    """A monotonically increasing count, optionally per label set."""

    kind = "counter"

    def __init__(self, name: str, help_text: str, labelnames: tuple[str, ...] = ()) -> None:
        super().__init__(name, help_text, labelnames)
        self._values: dict[tuple[str, ...], float] = {}
        if not self.labelnames:
            self._values[()] = 0.0

    def inc(self, amount: float = 1.0, **labels: str) -> None:
        if amount < 0:
            raise ValueError(f"counter {self.name} can only increase, got {amount}")
        key = self._key(labels)
        with self._lock:
            self._values[key] = self._values.get(key, 0.0) + amount

    def touch(self, **labels: str) -> None:
        """Make a label set appear (at 0) before its first increment."""
        key = self._key(labels)
        with self._lock:
            self._values.setdefault(key, 0.0)

    def value(self, **labels: str) -> float:
        with self._lock:
            return self._values.get(self._key(labels), 0.0)

    def remove(self, **labels: str) -> None:
        """Forget one label set (a reclaimed stream), so label sets stay bounded."""
        key = self._key(labels)
        with self._lock:
            self._values.pop(key, None)

    def values(self) -> dict[tuple[str, ...], float]:
        with self._lock:
            return dict(self._values)

    def render(self) -> list[str]:
        lines = self.header()
        for key, value in sorted(self.values().items()):
            lines.append(f"{self.name}{_labels(self.labelnames, key)} {_fmt(value)}")
        return lines


class Gauge(Counter):
    """A value that goes up and down (e.g. bodies tracked, degraded flag)."""

    kind = "gauge"

    def set(self, value: float, **labels: str) -> None:
        key = self._key(labels)
        with self._lock:
            self._values[key] = float(value)

    def inc(self, amount: float = 1.0, **labels: str) -> None:
        key = self._key(labels)
        with self._lock:
            self._values[key] = self._values.get(key, 0.0) + amount


class Histogram(_Family):
    """Cumulative-bucket histogram; also keeps a bounded reservoir for quantiles.

    The reservoir (last ``keep`` observations) serves the status line and benchmark
    p50/p99; the exported form is the standard ``_bucket``/``_sum``/``_count``.
    """

    kind = "histogram"

    def __init__(
        self,
        name: str,
        help_text: str,
        buckets: tuple[float, ...] = LATENCY_BUCKETS_S,
        keep: int = 4096,
    ) -> None:
        super().__init__(name, help_text, ())
        self.buckets = tuple(sorted(buckets))
        self._counts = [0] * (len(self.buckets) + 1)  # last one is +Inf
        self._sum = 0.0
        self._count = 0
        self._recent: list[float] = []
        self._keep = int(keep)
        self._next = 0

    def observe(self, value: float) -> None:
        value = float(value)
        i = bisect.bisect_left(self.buckets, value)
        with self._lock:
            self._counts[i] += 1
            self._sum += value
            self._count += 1
            if len(self._recent) < self._keep:
                self._recent.append(value)
            else:
                self._recent[self._next] = value
                self._next = (self._next + 1) % self._keep

    @property
    def count(self) -> int:
        with self._lock:
            return self._count

    def quantile(self, q: float) -> float:
        """Quantile ``q`` in [0, 1] of the recent observations (NaN if none)."""
        with self._lock:
            recent = sorted(self._recent)
        if not recent:
            return float("nan")
        idx = min(len(recent) - 1, max(0, int(math.ceil(q * len(recent))) - 1))
        return recent[idx]

    def render(self) -> list[str]:
        with self._lock:
            counts = list(self._counts)
            total, count = self._sum, self._count
        lines = self.header()
        cumulative = 0
        for bound, c in zip(self.buckets + (math.inf,), counts):
            cumulative += c
            lines.append(f'{self.name}_bucket{{le="{_fmt(bound)}"}} {cumulative}')
        lines.append(f"{self.name}_sum {_fmt(total)}")
        lines.append(f"{self.name}_count {count}")
        return lines


class Registry:
    """An ordered set of metric families rendered together."""

    def __init__(self) -> None:
        self._families: dict[str, _Family] = {}

    def add(self, family: _Family) -> _Family:
        if family.name in self._families:
            raise ValueError(f"metric {family.name} registered twice")
        self._families[family.name] = family
        return family

    def counter(self, name: str, help_text: str, labelnames: tuple[str, ...] = ()) -> Counter:
        return self.add(Counter(name, help_text, labelnames))  # type: ignore[return-value]

    def gauge(self, name: str, help_text: str, labelnames: tuple[str, ...] = ()) -> Gauge:
        return self.add(Gauge(name, help_text, labelnames))  # type: ignore[return-value]

    def histogram(self, name: str, help_text: str, buckets: tuple[float, ...] = LATENCY_BUCKETS_S) -> Histogram:
        return self.add(Histogram(name, help_text, buckets))  # type: ignore[return-value]

    def render(self) -> str:
        """The whole registry in the Prometheus text exposition format (0.0.4)."""
        lines: list[str] = []
        for family in self._families.values():
            lines.extend(family.render())  # type: ignore[attr-defined]
        return "\n".join(lines) + "\n"


def parse_prometheus_text(text: str) -> dict[str, float]:
    """Parse exposition text into ``{'name{labels}': value}`` (for tests and tools)."""
    out: dict[str, float] = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, _, value = line.rpartition(" ")
        out[key] = float(value.replace("+Inf", "inf"))
    return out


class _BoundedHTTPServer(ThreadingHTTPServer):
    """A threading HTTP server that serves at most ``max_connections`` clients at once.

    A connection beyond the bound is closed at once (counted in ``refused``), so slow
    or idle clients can hold at most that many threads; each of those is released
    after the handler's socket timeout.
    """

    daemon_threads = True
    request_queue_size = 64  # listen backlog: a burst of clients is accepted (and refused) quickly

    def __init__(self, address, handler, max_connections: int) -> None:
        self._slots = threading.BoundedSemaphore(int(max_connections))
        self.refused = 0
        super().__init__(address, handler)

    def process_request(self, request, client_address) -> None:
        if not self._slots.acquire(blocking=False):
            self.refused += 1
            self.shutdown_request(request)
            return
        try:
            super().process_request(request, client_address)
        except Exception:
            self._slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._slots.release()


class MetricsServer:
    """Serve ``registry.render()`` at ``http://HOST:PORT/metrics`` from a daemon thread.

    ``port=0`` picks a free port; the bound one is ``self.port``. A client has
    ``timeout_s`` to send its request (and to take the answer) before its connection
    is closed, and at most ``max_connections`` are served at once (more are closed on
    accept), so slow clients cannot pile up threads.
    """

    def __init__(
        self, registry: Registry, port: int, host: str = "127.0.0.1", *, timeout_s: float = 5.0,
        max_connections: int = 8,
    ) -> None:
        reg = registry

        class Handler(BaseHTTPRequestHandler):
            timeout = float(timeout_s)  # socket timeout: a silent client is dropped after this

            def do_GET(self) -> None:  # noqa: N802 (http.server API)
                if self.path.split("?")[0] not in ("/metrics", "/"):
                    self.send_error(404, "only /metrics is served here")
                    return
                body = reg.render().encode("utf-8")
                self.send_response(200)
                self.send_header("Content-Type", "text/plain; version=0.0.4; charset=utf-8")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format: str, *args: object) -> None:  # keep stderr for the status line
                return

        self._httpd = _BoundedHTTPServer((host, int(port)), Handler, max_connections)
        self.host = host
        self.port = int(self._httpd.server_address[1])
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="metrics-http", daemon=True)

    def start(self) -> "MetricsServer":
        self._thread.start()
        return self

    def close(self) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()
