"""What ``streamfix view`` runs: a bridge from a service's topics plus the web server.

:class:`Viewer` watches a running service (``streamfix view tcp://127.0.0.1:5556``, or
``streamfix serve --view`` beside the service). :class:`FileService` is the service
``streamfix view FILE`` starts for itself: the recording played at its own timing
(:class:`streamfix.service.sources.ReplaySource`) through the same engines as
``streamfix serve`` (:class:`streamfix.service.server.Service`), published on a private
loopback port that only the viewer subscribes to. The page then shows exactly what a
service would publish for that file, with no service started by hand.
"""
from __future__ import annotations

import threading

from .board import FrameBoard
from .bridge import ZmqBridge
from .server import DEFAULT_PORT, ViewerServer

__all__ = ["Viewer", "FileService"]


class Viewer:
    """Subscribe to ``endpoint`` (a service's ``--out``) and serve the page on ``host:port``."""

    def __init__(self, endpoint: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                 title: str | None = None, hold_s: float = 5.0) -> None:
        self.endpoint = endpoint
        self.board = FrameBoard(hold_s=hold_s)
        self.bridge = ZmqBridge(endpoint, self.board)
        try:
            self.server = ViewerServer(
                self.board, host, port, title=title or f"streamfix view {endpoint}",
                status_extra=lambda: {"endpoint": endpoint, "zmq": dict(self.bridge.counters)},
            )
        except BaseException:
            self.bridge.close()
            raise
        self.bridge.start()

    @property
    def url(self) -> str:
        return self.server.url

    def close(self) -> None:
        self.server.close()
        self.bridge.close()

    def __enter__(self) -> "Viewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class FileService:
    """A private service playing ``path`` (real time x ``rate``, looped) on a loopback PUB.

    ``engine`` is a ``streamfix serve --engine`` name. :attr:`endpoint` is where to
    subscribe; the service runs on a daemon thread until :meth:`close` (or the end of
    the file when ``loop`` is False).
    """

    def __init__(self, path: str, *, rate: float = 1.0, loop: bool = True, engine: str = "streamfix",
                 start_delay_s: float = 0.5) -> None:
        from ..service.engines import EngineOptions, engine_factory
        from ..service.publisher import ServicePublisher
        from ..service.server import Service
        from ..service.sources import ReplaySource

        source = ReplaySource(str(path), rate=rate, loop=loop)
        self.description = source.describe()
        publisher = ServicePublisher("tcp://127.0.0.1:*", linger_ms=0)
        self.endpoint = publisher.endpoint
        self.service = Service(source, publisher, engine_factory(engine, EngineOptions()),
                               status_interval_s=0, start_delay_s=start_delay_s, idle_timeout_s=2.0)
        self.result: int | None = None
        self._thread = threading.Thread(target=self._run, name="streamfix-view-service", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.result = self.service.run()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def close(self, timeout_s: float = 10.0) -> None:
        if self._thread.is_alive():
            try:
                self.service.stop()
            except KeyboardInterrupt:
                pass
            self._thread.join(timeout_s)
