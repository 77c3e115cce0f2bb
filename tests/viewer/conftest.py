"""Headless Chromium for the page tests (Debian's ``chromium`` package; skipped where it is missing)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars"]


def chromium_path() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture
def screenshot(tmp_path):
    """``screenshot(url, png, width, height)``: render a page in headless Chromium and save a PNG."""
    exe = chromium_path()
    if exe is None:
        pytest.skip("headless Chromium is not installed (apt-get install chromium)")

    def shoot(url: str, png: Path, width: int = 1280, height: int = 1600) -> Path:
        profile = tmp_path / "chromium-profile"
        cmd = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
               f"--screenshot={png}", url]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert png.is_file(), f"chromium wrote no screenshot (exit {proc.returncode}): {proc.stderr[-2000:]}"
        return png

    return shoot


class Page:
    """A page in headless Chromium driven over the DevTools protocol (websockets, which viser brings)."""

    def __init__(self, exe: str, profile: Path, width: int, height: int):
        import json
        import re
        import time
        import urllib.request

        self.proc = subprocess.Popen(
            [exe, *CHROMIUM_FLAGS, "--enable-unsafe-swiftshader", f"--user-data-dir={profile}",
             f"--window-size={width},{height}", "--remote-debugging-port=0", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        port, deadline = None, time.monotonic() + 60
        while port is None and time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            if not line and self.proc.poll() is not None:
                break
            m = re.search(r"DevTools listening on ws://[^:]+:(\d+)/", line)
            port = int(m.group(1)) if m else None
        assert port is not None, "chromium did not start its DevTools server"
        targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read())
        page = next(t for t in targets if t["type"] == "page")
        from websockets.sync.client import connect

        self.ws = connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=30)
        self.next_id = 0

    def call(self, method: str, **params):
        import json

        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=60))
            if msg.get("id") == self.next_id:
                assert "error" not in msg, msg["error"]
                return msg["result"]

    def text(self) -> str:
        return self.call("Runtime.evaluate", expression="document.body ? document.body.innerText : ''")[
            "result"].get("value", "")

    def wait_for_text(self, needle: str, timeout: float = 90) -> str:
        import time

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = self.text()
            if needle in text:
                return text
            time.sleep(0.5)
        raise AssertionError(f"{needle!r} did not appear in the page; it shows: {self.text()[:500]!r}")

    def screenshot(self, png: Path) -> Path:
        import base64

        png.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"]))
        return png

    def close(self) -> None:
        try:
            self.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()


@pytest.fixture
def browser_page(tmp_path):
    """A :class:`Page` (1280x800) in headless Chromium, closed after the test."""
    exe = chromium_path()
    if exe is None:
        pytest.skip("headless Chromium is not installed (apt-get install chromium)")
    pytest.importorskip("websockets.sync.client", reason="websockets (the viewer extra) is not installed")
    page = Page(exe, tmp_path / "chromium-cdp", 1280, 800)
    yield page
    page.close()
