"""The identity of a file: its size and modification time as build tools trust them, or the SHA-256 of its
bytes where another machine must recognise it (shipped weights, exported graphs)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def file_identity(path: str | Path) -> str:
    """Size and modification time of a file (what ``make`` trusts): cheap, and changes with any edit."""
    st = Path(path).stat()
    return f"{st.st_size}:{st.st_mtime_ns}"


def file_sha256(path: str | Path) -> str:
    """The hex SHA-256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
