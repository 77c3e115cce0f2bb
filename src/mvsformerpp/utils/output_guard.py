"""Claiming an output folder: never over the input, never over someone else's files, one run at a time.

:func:`claim_output_folder` is what every command that writes a folder goes through:

* the folder must not be the input, contain it or lie inside it (a run would rewrite the photos,
  cams and ``pair.txt`` it reads);
* an existing, non-empty folder must carry the marker file this package writes (``.mvsformerpp``),
  so another scene's folder or any folder of the user's is refused instead of mixed into;
* an advisory lock (``fcntl.flock`` on ``.mvsformerpp.lock``) admits one run at a time; the second
  one stops and names the process (pid, host, start time) that holds the folder (in a job of several
  processes started by torchrun, rank 0 holds it for the job: ``RANK``/``WORLD_SIZE``);
* temporary files that a killed run left behind (``.NAME.XXXXXXXX.tmp``, see :mod:`.atomic`) are
  removed once the lock is held, and a folder that the failed run created and left empty is removed.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import socket
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from mvsformerpp.errors import InputError
from mvsformerpp.utils.distributed import env_rank

MARKER = ".mvsformerpp"
LOCK = ".mvsformerpp.lock"
# Names of the temporaries that utils.atomic and the image linker write beside their target.
_TEMPORARY = re.compile(r"^\..+\.(tmp|link)$")


class FolderBusyError(InputError):
    """Another process holds the output folder's lock."""


def _inside(a: Path, b: Path) -> bool:
    """``a`` is ``b`` or lies inside it (both resolved)."""
    return a == b or b in a.parents


def check_not_input(out: Path, inputs: Sequence[str | Path]) -> None:
    """Refuse an output folder that is, contains or lies inside one of ``inputs`` (files: their folder)."""
    o = out.resolve()
    for given in inputs:
        p = Path(given).resolve()
        root = p if p.is_dir() else p.parent
        if _inside(o, root) or _inside(root, o):
            how = "is" if o == root else ("lies inside" if _inside(o, root) else "contains")
            raise InputError(f"the output folder {how} the input {given}; writing there would overwrite or mix "
                             "with the input files. Choose an -o folder outside the input", out)


def written_by(out: Path) -> str | None:
    """The command that wrote ``out`` according to its marker (older reconstruct outputs: by their files)."""
    try:
        return json.loads((out / MARKER).read_text()).get("written_by")
    except (OSError, ValueError, AttributeError):
        pass
    if (out / "progress.json").is_file() and (out / "config.json").is_file():
        return "mvsformerpp reconstruct"
    if (out / "config.yaml").is_file() and (out / "metrics.jsonl").is_file():  # a training run
        return "mvsformerpp train"
    return None


def check_owned(out: Path, kind: str, reuse: bool = True) -> None:
    """Refuse an existing non-empty folder unless ``reuse`` and an earlier run of ``kind`` wrote it."""
    if not out.exists():
        return
    if not out.is_dir():
        raise InputError("the output path exists and is not a folder; choose another -o", out)
    entries = [p.name for p in out.iterdir() if p.name not in (LOCK, MARKER)]
    if not entries or (reuse and written_by(out) == f"mvsformerpp {kind}"):
        return
    shown = ", ".join(sorted(entries)[:4]) + (" ..." if len(entries) > 4 else "")
    whose = "" if reuse else " (it must be new or empty)"
    raise InputError(f"the output folder is not empty and was not written by mvsformerpp {kind}{whose}: it holds "
                     f"{shown}. Choose a new or empty folder so that no file of yours is overwritten", out)


def remove_temporaries(folder: Path) -> int:
    """Delete the ``.NAME.XXXX.tmp`` / ``.NAME.link`` files an interrupted run left; returns how many."""
    removed = 0
    for dirpath, _, files in os.walk(folder):
        for name in files:
            if _TEMPORARY.match(name):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(os.path.join(dirpath, name))
                    removed += 1
    return removed


_HELD: set[str] = set()
"""Folders whose lock this process holds (:func:`claim_output_file` inside them shares the hold: the fusion
of a ``reconstruct`` run)."""


@contextlib.contextmanager
def folder_lock(folder: Path) -> Iterator[None]:
    """Hold the folder's advisory lock for the block; raise :class:`FolderBusyError` if another run holds it."""
    import fcntl

    key = os.path.realpath(folder)
    path = folder / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_holder(fd)
            raise FolderBusyError(f"another mvsformerpp run ({holder}) is writing to this folder; wait for it to "
                                  "finish or choose another -o", folder) from None
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        _HELD.add(key)
        try:
            yield
        finally:
            _HELD.discard(key)
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _read_holder(fd: int) -> str:
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
        return f"pid {info['pid']} on {info['host']}, started {info['started']}"
    except (OSError, ValueError, KeyError):
        return "a process that has just started"


@contextlib.contextmanager
def claim_output_folder(out: str | Path, inputs: Sequence[str | Path] = (), kind: str = "reconstruct",
                        reuse: bool = True) -> Iterator[Path]:
    """Check, create and lock ``out`` for one run of ``kind`` (see the module docstring); yields its path.

    ``reuse``: an earlier output of the same ``kind`` may be continued (resumable commands); False
    accepts only a new or empty folder.
    """
    out = Path(out)
    check_not_input(out, inputs)
    check_owned(out, kind, reuse)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create the output folder ({e.strerror}); choose another -o", out) from e
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError("the output folder is not writable (permission denied or a read-only file system); "
                         "choose another -o", out)
    rank, world = env_rank().rank, env_rank().world_size
    # One job of several processes (torchrun): rank 0 holds the lock for all of them, and nobody removes
    # temporaries, which may be another rank's file in flight.
    held = contextlib.ExitStack()
    try:
        if rank == 0:
            held.enter_context(folder_lock(out))
            if written_by(out) != f"mvsformerpp {kind}":
                (out / MARKER).write_text(json.dumps({"written_by": f"mvsformerpp {kind}"}) + "\n")
        if world == 1:
            remove_temporaries(out)
    except BaseException as e:
        held.close()
        if created:
            _remove_if_unused(out)
        if isinstance(e, OSError) and e.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
            raise InputError(f"cannot write to the output folder ({e.strerror}); choose another -o", out) from e
        raise
    with held:
        try:
            yield out
        except BaseException:
            if created:
                _remove_if_unused(out)
            raise


def _remove_if_unused(out: Path) -> None:
    """Remove a folder this run created when it holds no file but the marker and the lock."""
    with contextlib.suppress(OSError):
        files = [Path(d, f) for d, _, names in os.walk(out) for f in names]
        if all(f.parent == out and f.name in (MARKER, LOCK) for f in files):
            shutil.rmtree(out, ignore_errors=True)


def check_replaceable(path: str | Path, magics: Sequence[bytes], what: str, flag: str = "-o") -> None:
    """Refuse to replace ``path`` unless it is new or a file of the kind about to be written (it starts with
    one of ``magics``): every command that writes a file replaces only its own kind, never a photo or a
    document that happens to sit at that name."""
    path = Path(path)
    if not path.exists():
        return
    if not path.is_file():
        raise InputError(f"the output exists and is not a file; choose another {flag} {what}", path)
    with open(path, "rb") as f:
        head = f.read(max(len(m) for m in magics))
    if not any(head.startswith(m) for m in magics):
        article = "an" if what[:1] in "AEIOUaeiou" or what.startswith("HTML") else "a"
        raise InputError(f"the output exists and is not {article} {what} file; choose another {flag} so that it is "
                         "not overwritten", path)


@contextlib.contextmanager
def claim_output_file(path: str | Path, magic: bytes, what: str) -> Iterator[Path]:
    """Check that ``path`` is new or a file of this kind (it starts with ``magic``), then hold it for the block.

    Inside a folder an earlier run of this package wrote, the folder's lock is held too (fusing into a
    folder that another ``reconstruct`` is writing stops with the holder's name; the run that holds it in
    this process shares its hold); the temporaries a killed run
    left for this file name are removed.
    """
    path = Path(path)
    check_replaceable(path, (magic,), what)
    folder = path.parent
    held_here = os.path.realpath(folder) in _HELD  # (a reconstruct run of this process fusing into its folder)
    lock = folder_lock(folder) if written_by(folder) is not None and not held_here else contextlib.nullcontext()
    with lock:
        if folder.is_dir():
            for p in folder.glob(f".{glob_escape(path.name)}.*.tmp"):
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
        yield path


@contextlib.contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """Turn a full disk, a denied permission or a read-only file system while writing ``path`` into InputError."""
    try:
        yield
    except OSError as e:
        if e.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR):
            raise
        advice = ("free some space and run the command again" if e.errno in (errno.ENOSPC, errno.EDQUOT)
                  else "choose a location you can write to")
        raise InputError(f"cannot write this file ({e.strerror}); {advice}. Files written before are kept",
                         path) from e


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)
