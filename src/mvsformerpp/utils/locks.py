"""Advisory locks that admit one run at a time to an output, and name the run that holds it.

A lock is ``fcntl.flock`` on a small file that records its holder (pid, host, start time); the kernel
releases it when the holder dies, so a killed run never leaves an output locked. A run folder keeps its
lock file (``.mvsformerpp.lock``); an output file or folder in a folder of the user's is locked by
``.NAME.lock`` beside it, removed when the run ends.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from mvsformerpp.errors import InputError


class FolderBusyError(InputError):
    """Another process holds the output's lock."""


HELD: set[str] = set()
"""Real paths of the outputs whose lock this process holds (a claim inside one shares the hold: the fusion of
a ``reconstruct`` run into its own folder)."""


@contextlib.contextmanager
def hold_lock(lock: Path, target: Path, what: str = "folder", remove: bool = False) -> Iterator[None]:
    """Hold ``lock`` (created if need be) for the block, as the lock of ``target`` (a ``what``: folder or file).

    Raises :class:`FolderBusyError` naming the holder when another process holds it, and an
    :class:`InputError` naming ``target`` (not the lock file) when it cannot be created. ``remove``: delete
    the lock file at the end (a lock beside an output in a folder of the user's).
    """
    import fcntl

    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as e:
            if e.errno not in (errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT):
                raise
            raise InputError(f"cannot write to the output {what} ({e.strerror}); choose a location you can write "
                             "to", target) from e
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            os.close(fd)
            where = "to this folder" if what == "folder" else f"this {what}"
            raise FolderBusyError(f"another mvsformerpp run ({holder}) is writing {where}; wait for it to finish "
                                  "or choose another output", target) from None
        if not remove or _same_file(fd, lock):
            break
        os.close(fd)  # the lock file was removed by its last holder after this process opened it: take a new one
    key = os.path.realpath(target)
    try:
        info = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        with contextlib.suppress(OSError):  # (a full disk: the lock holds all the same)
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(info).encode(), 0)
        HELD.add(key)
        try:
            yield
        finally:
            HELD.discard(key)
            if remove:
                with contextlib.suppress(OSError):
                    os.unlink(lock)
            else:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _same_file(fd: int, path: Path) -> bool:
    try:
        return os.path.samestat(os.fstat(fd), os.stat(path))
    except FileNotFoundError:
        return False


def _read_holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
        return f"pid {info['pid']} on {info['host']}, started {info['started']}"
    except (OSError, ValueError, KeyError):
        return "a process that has just started"
