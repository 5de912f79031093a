"""The viewer's web side: one port on 127.0.0.1 serving the page, its WebSocket and a status.

Routes: ``/`` the page (``static/index.html`` with ``viewer.js``; shipped in the package,
no Node.js needed), ``/ws`` the WebSocket the page reads frames from, ``/status`` a JSON
snapshot (board counters, per-page queue and drops, what each page last reported of
itself: frames drawn, joints drawn, render rate).

WebSocket messages, server to page (JSON text): ``{"type": "frames", "records": [...],
"layouts": {stream: layout}, "bridge": {...}}`` where ``records`` are the paired instants
this page has not had yet, oldest first per stream (at most the board's few newest per
stream: :class:`~streamfix.viewer.board.FrameBoard`), and ``layouts`` holds only streams
the page has not seen yet. Page to server: ``{"type": "ack"}`` after each
frames message, and ``{"type": "status", ...}`` now and then.

Flow control, so nothing queues anywhere: the server sends a frames message only while
fewer than ``window`` are unacknowledged; until the page acknowledges, the board keeps
pushing the oldest records out (counted as dropped for that page). A slow page or
network therefore sees fewer, newer frames, never older ones late.
"""
from __future__ import annotations

import itertools
import json
import logging
import threading
from importlib import resources
from typing import Callable

from .board import FrameBoard

__all__ = ["ViewerServer", "DEFAULT_PORT"]

DEFAULT_PORT = 8765
_STATIC = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/index.html": ("index.html", "text/html; charset=utf-8"),
    "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
}


def _static(name: str) -> bytes:
    return resources.files(__package__).joinpath("static", name).read_bytes()


class ViewerServer:
    """Serve the viewer page and stream a board's records to every connected page.

    ``port`` 0 picks a free port (see :attr:`port`). ``status_extra()`` adds to
    ``/status`` (e.g. the bridge's ZeroMQ counters). Runs on daemon threads; ``close()``
    stops it.
    """

    def __init__(
        self,
        board: FrameBoard,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        *,
        title: str = "streamfix view",
        window: int = 2,
        status_extra: Callable[[], dict] | None = None,
    ) -> None:
        from websockets.sync.server import serve

        if window < 1:
            raise ValueError(f"window must be >= 1 unacknowledged message, got {window}")
        self.board = board
        self.title = title
        self.window = int(window)
        self.status_extra = status_extra
        self._files = {path: (_static(name), ctype) for path, (name, ctype) in _STATIC.items()}
        self._clients: dict[int, dict] = {}
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        quiet = logging.getLogger("streamfix.viewer.websockets")
        quiet.setLevel(logging.WARNING)  # not one INFO line per page load in `serve --view`'s log
        self._server = serve(self._handle, host, port, process_request=self._http, compression=None,
                             ping_interval=None, max_size=2**20, logger=quiet)
        self.host, self.port = self._server.socket.getsockname()[:2]
        self._thread = threading.Thread(target=self._server.serve_forever, name="streamfix-view-http", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    # ------------------------------------------------------------------ HTTP
    def _http(self, connection, request):
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        path = request.path.split("?", 1)[0]
        if path == "/ws":
            return None  # go on with the WebSocket handshake
        if path == "/status":
            body, ctype = json.dumps(self.status(), allow_nan=False).encode(), "application/json"
        elif path in self._files:
            body, ctype = self._files[path]
        else:
            body, ctype = f"not found: {path}\n".encode(), "text/plain; charset=utf-8"
            return Response(404, "Not Found", Headers([("Content-Type", ctype), ("Content-Length", str(len(body)))]), body)
        headers = Headers([("Content-Type", ctype), ("Content-Length", str(len(body))), ("Cache-Control", "no-store")])
        return Response(200, "OK", headers, body)

    def status(self) -> dict:
        """What ``/status`` serves: board counters, held frames, every page's queue and report."""
        with self._lock:
            clients = [dict(c["reader"].stats(), page=c["page"], unacked=c["unacked"]) for c in self._clients.values()]
        out = {"title": self.title, "board": dict(self.board.counters), "held": self.board.held_frames(),
               "streams": sorted(self.board.layouts), "clients": clients}
        if self.status_extra is not None:
            out.update(self.status_extra())
        return out

    # ------------------------------------------------------------------ WebSocket
    def _handle(self, connection) -> None:
        reader = self.board.reader()
        me = {"reader": reader, "page": None, "unacked": 0}
        cid = next(self._ids)
        with self._lock:
            self._clients[cid] = me
        sent_layouts: set[str] = set()
        try:
            connection.send(json.dumps({"type": "hello", "title": self.title}))
            while True:
                self._read_page(connection, me, 0.0 if me["unacked"] < self.window else 0.05)
                if me["unacked"] >= self.window:
                    continue
                records = reader.take(0.05)
                if not records:
                    continue
                layouts = {s: self.board.layouts[s] for s in {r["stream"] for r in records} - sent_layouts
                           if s in self.board.layouts}
                sent_layouts.update(layouts)
                msg = {"type": "frames", "records": records, "layouts": layouts, "bridge": reader.stats()}
                connection.send(json.dumps(msg, allow_nan=False))
                me["unacked"] += 1
        except Exception as exc:  # the page went away (ConnectionClosed) or sent garbage
            from websockets.exceptions import ConnectionClosed

            if not isinstance(exc, (ConnectionClosed, ValueError)):
                raise
        finally:
            with self._lock:
                self._clients.pop(cid, None)

    @staticmethod
    def _read_page(connection, me: dict, timeout_s: float) -> None:
        """Take every message the page sent (acks, status reports) without blocking long."""
        while True:
            try:
                text = connection.recv(timeout=timeout_s)
            except TimeoutError:
                return
            msg = json.loads(text)
            if msg.get("type") == "ack":
                me["unacked"] = max(0, me["unacked"] - 1)
            elif msg.get("type") == "status":
                me["page"] = msg
            timeout_s = 0.0

    def close(self) -> None:
        self._server.shutdown()
        self._thread.join(2.0)
