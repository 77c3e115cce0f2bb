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
