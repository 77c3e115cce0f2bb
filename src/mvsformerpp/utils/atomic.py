"""Write files atomically: to a temporary name in the same folder, then rename.

An interrupted run never leaves a half-written file under the final name. The file gets the
permissions a plain ``open`` would give it (0666 less the umask, 0644 by default), not mkstemp's 0600.
A run killed mid-write leaves ``.NAME.XXXXXXXX.tmp`` behind; :mod:`.output_guard` removes those.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success it replaces ``path``, on error it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as e:  # (a read-only or full place: the error names the file, not its temporary)
        e.filename = str(path)
        raise
    try:
        os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.filename is None:  # a failed write (a full disk): name the file
            e.filename = str(path)
        raise


def current_umask() -> int:
    """The process's umask (read without changing it where /proc allows)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_open(path, "wb") as f:
        f.write(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` as UTF-8; a file name with bytes that are not UTF-8 (read as surrogates, as Python reads
    such names) is written back as those bytes, never an error."""
    atomic_write_bytes(path, text.encode("utf-8", "surrogateescape"))
