"""Drive a headless Chromium over the Chrome DevTools Protocol (CDP): load, evaluate, screenshot.

Used by the viewer's browser test and ``benchmarks/bench_viewer.py`` to check the page
from inside itself (``window.sfStatus``) with no Selenium or Playwright: Chromium is
started with ``--remote-debugging-port=0``, the port it picked is read from
``DevToolsActivePort`` in its profile directory, and one page target is driven over
its WebSocket with ``Runtime.evaluate`` and ``Page.captureScreenshot``.
"""
from __future__ import annotations

import base64
import contextlib
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

__all__ = ["HeadlessChromium", "find_chromium"]

_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable (``$CHROMIUM`` first), or None."""
    env = os.environ.get("CHROMIUM")
    if env:
        return env
    for name in _CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


class HeadlessChromium:
    """A headless Chromium with one page, driven over CDP.

    ``size`` is the window in CSS pixels. Use as a context manager; :meth:`close`
    terminates the browser and removes its temporary profile.
    """

    def __init__(self, executable: str | None = None, *, size: tuple[int, int] = (1280, 900),
                 start_timeout_s: float = 30.0) -> None:
        from websockets.sync.client import connect

        exe = executable or find_chromium()
        if exe is None:
            raise FileNotFoundError(f"no Chromium found (looked for $CHROMIUM and {', '.join(_CANDIDATES)})")
        self._profile = tempfile.mkdtemp(prefix="sf-chromium-")
        self._stack = contextlib.ExitStack()
        args = [
            exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
            "--no-first-run", "--no-default-browser-check", "--disable-extensions",
            "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
            "--disable-backgrounding-occluded-windows", f"--window-size={size[0]},{size[1]}",
            "--remote-debugging-port=0", "--remote-allow-origins=*", f"--user-data-dir={self._profile}",
            "about:blank",
        ]
        self._log = open(Path(self._profile) / "chromium.log", "wb")  # a pipe left unread could block it
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=self._log)
        try:
            port = self._wait_port(start_timeout_s)
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                targets = json.load(r)
            page = next(t for t in targets if t.get("type") == "page")
            self._ws = self._stack.enter_context(connect(page["webSocketDebuggerUrl"], max_size=64 * 2**20, open_timeout=10))
        except BaseException:
            self.close()
            raise
        self._ids = itertools.count(1)
        self.send("Page.enable")
        self.send("Runtime.enable")

    def _wait_port(self, timeout_s: float) -> int:
        marker = Path(self._profile) / "DevToolsActivePort"
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                err = (Path(self._profile) / "chromium.log").read_text(errors="replace")[-2000:]
                raise RuntimeError(f"chromium exited with status {self.proc.returncode}: {err}")
            if marker.exists():
                text = marker.read_text().split()
                if text:
                    return int(text[0])
            time.sleep(0.05)
        raise TimeoutError(f"chromium did not open its DevTools port within {timeout_s} s")

    def send(self, method: str, params: dict | None = None, timeout_s: float = 30.0) -> dict:
        """Send one CDP command and return its ``result`` (events in between are skipped)."""
        mid = next(self._ids)
        self._ws.send(json.dumps({"id": mid, "method": method, "params": params or {}}))
        deadline = time.monotonic() + timeout_s
        while True:
            msg = json.loads(self._ws.recv(timeout=max(0.01, deadline - time.monotonic())))
            if msg.get("id") == mid:
                if "error" in msg:
                    raise RuntimeError(f"CDP {method} failed: {msg['error']}")
                return msg.get("result", {})

    def goto(self, url: str) -> None:
        self.send("Page.navigate", {"url": url})

    def evaluate(self, expression: str):
        """Value of a JavaScript expression in the page (JSON-serialisable values)."""
        res = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True})
        if "exceptionDetails" in res:
            raise RuntimeError(f"page raised evaluating {expression!r}: {res['exceptionDetails']}")
        return res["result"].get("value")

    def wait_for(self, expression: str, timeout_s: float = 20.0, interval_s: float = 0.1):
        """Poll until the expression is truthy; returns its value, TimeoutError otherwise."""
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            try:
                last = self.evaluate(expression)
            except RuntimeError:
                last = None  # page still loading
            if last:
                return last
            time.sleep(interval_s)
        raise TimeoutError(f"{expression!r} still falsy after {timeout_s} s (last value {last!r})")

    def screenshot(self, path: str | Path) -> Path:
        """Save a PNG of the page's viewport."""
        data = self.send("Page.captureScreenshot", {"format": "png"})["data"]
        path = Path(path)
        path.write_bytes(base64.b64decode(data))
        return path

    def close(self) -> None:
        self._stack.close()  # the DevTools WebSocket
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self._log.close()
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> "HeadlessChromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
