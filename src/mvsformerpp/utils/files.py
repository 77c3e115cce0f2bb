"""The identity of a file as build tools trust it: size and modification time."""

from __future__ import annotations

from pathlib import Path


def file_identity(path: str | Path) -> str:
    """Size and modification time of a file (what ``make`` trusts): cheap, and changes with any edit."""
    st = Path(path).stat()
    return f"{st.st_size}:{st.st_mtime_ns}"
