"""Live browser viewer of raw versus cleaned skeletons (``streamfix view``).

A service's ``raw``/``live``/``clean`` topics are paired by instant on a
:class:`FrameBoard` that keeps the newest few (:mod:`.bridge` feeds it from ZeroMQ), streamed to a page over
WebSocket by :class:`ViewerServer`; the page (``static/``, plain JavaScript, no build
step) draws every body in 3D and rolling plots on ``requestAnimationFrame``.
:mod:`.headless` drives a headless Chromium over the DevTools protocol (tests, benchmark).
"""
from .app import FileService, Viewer
from .board import BoardReader, FrameBoard
from .server import DEFAULT_PORT, ViewerServer

__all__ = ["Viewer", "FileService", "FrameBoard", "BoardReader", "ViewerServer", "DEFAULT_PORT"]
