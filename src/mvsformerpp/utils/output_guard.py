"""The one output guard: every command and Python function of this package that writes goes through it.

What it holds, for folders (:func:`claim_output_folder`), single files (:func:`claim_output_file`) and folders
replaced as a whole (:func:`~mvsformerpp.utils.output_tree.claim_output_tree`) alike:

* never inside the installed package (its weights record, code and sample scenes), never into an input
  (the output is not an input file, and an output folder neither is, contains nor lies inside an input
  folder), never under a file, never a name longer than the file system allows;
* an existing output is replaced or continued only when this package wrote it as the kind being written:
  a folder by its marker file (``.mvsformerpp``, which names the command, and the settings where a rerun
  completes the output), a file by the marker of its kind (:mod:`.file_kinds`); a run folder's own files
  (``fused.ply``, ``report.html``) are taken by no other kind;
* names made from data (scene names, view names) stay inside the folder they are written to (:func:`child`);
* one run at a time: an advisory lock (:mod:`.locks`), whose holder the second run names;
* temporaries that a killed run left behind (``.NAME.XXXXXXXX.tmp`` files and folders, see :mod:`.atomic`)
  are removed by the next run once it holds the lock, and a folder that a failed run created and left
  empty is removed;
* a full disk, a read-only place or a denied permission while writing is one clear error that names the
  output, not its temporary (:func:`writing`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path

import mvsformerpp
from mvsformerpp.errors import InputError
from mvsformerpp.utils.distributed import env_rank
from mvsformerpp.utils.file_kinds import KINDS, FileKind
from mvsformerpp.utils.locks import HELD, FolderBusyError, hold_lock

__all__ = ["MARKER", "LOCK", "FolderBusyError", "check_output_path", "check_not_input", "check_not_input_file",
           "check_owned", "check_output_file", "check_output_folder", "check_replaceable", "claim_output_folder",
           "claim_output_file", "child", "folder_lock", "make_folders", "remove_temporaries", "writing", "written_by"]

MARKER = ".mvsformerpp"
LOCK = ".mvsformerpp.lock"
# Names of the temporaries that utils.atomic, the image linker and staged folders leave beside their target.
_TEMPORARY = re.compile(r"^\..+\.(tmp|link)$")
TEMPORARY_ROOM = len("..12345678.tmp")
"""Bytes an atomic write adds to a file's name for its temporary (``.NAME.XXXXXXXX.tmp``)."""


def package_root() -> Path:
    """The installed ``mvsformerpp`` package (its code, shipped weights record and sample scenes)."""

    return Path(mvsformerpp.__file__).resolve().parent


def _inside(a: Path, b: Path) -> bool:
    """``a`` is ``b`` or lies inside it (both resolved)."""
    return a == b or b in a.parents


def _name_max(path: Path) -> int:
    """The longest name the file system of ``path`` (its nearest existing folder) allows."""
    here = path.absolute().parent
    while not os.path.isdir(here) and here != here.parent:  # (isdir: False, not an error, for any bad path)
        here = here.parent
    try:
        return os.pathconf(here, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def check_output_path(path: str | Path, flag: str = "-o", room: int = 0) -> Path:
    """Refuse an output path that cannot be written, before any work: a name longer than the file system allows
    (less ``room`` for a temporary name), a path under a file, or a place inside the installed package."""
    path = Path(path)
    name_max = _name_max(path)
    for k, part in enumerate(path.parts):
        size, kept = len(os.fsencode(part)), room if k == len(path.parts) - 1 else 0
        if size > name_max - kept:
            more = f" ({kept} of the file system's {name_max} kept for the temporary name)" if kept else ""
            raise InputError(f"{flag}: a name in the path is {size} bytes long ({part[:20]}...), more than the "
                             f"{name_max - kept} allowed{more}; choose a shorter name")
    here = path.absolute().parent
    while not os.path.lexists(here) and here != here.parent:
        here = here.parent
    if not here.is_dir():
        raise InputError(f"the output lies under {here}, which is a file, not a folder; choose another {flag}", path)
    package = package_root()
    if _inside(Path(os.path.realpath(path)), package):
        raise InputError(f"the output lies inside the installed mvsformerpp package ({package}), whose files every "
                         f"run reads; choose another {flag} outside it", path)
    return path


def check_not_input(out: Path, inputs: Sequence[str | Path], flag: str = "-o") -> None:
    """Refuse an output folder that is, contains or lies inside one of the input folders, or is or contains one of
    the input files."""
    o = Path(out).resolve()
    for given in inputs:
        p = Path(given).resolve()
        if p.is_dir() and (_inside(o, p) or _inside(p, o)):
            how = "is" if o == p else ("lies inside" if _inside(o, p) else "contains")
        elif not p.is_dir() and _inside(p, o):
            how = "is" if o == p else "contains"
        else:
            continue
        raise InputError(f"the output folder {how} the input {given}; writing there would overwrite or mix with "
                         f"the input files. Choose another {flag} outside the input", out)


def check_not_input_file(path: Path, inputs: Sequence[str | Path], flag: str = "-o") -> None:
    """Refuse an output file that is one of the input files or lies inside one of the input folders."""
    r = Path(path).resolve()
    for given in inputs:
        p = Path(given).resolve()
        if r == p or (p.is_dir() and p in r.parents):
            how = "is" if r == p else "lies inside"
            raise InputError(f"the output {how} the input {given}; choose another {flag} so that no input is "
                             "overwritten", path)


def written_by(out: Path) -> str | None:
    """The command that wrote the folder ``out`` according to its marker (older outputs: by their files)."""
    record = _marker(out)
    if record is not None:
        return record.get("written_by")
    if (out / "progress.json").is_file() and (out / "config.json").is_file():
        return "mvsformerpp reconstruct"
    if (out / "config.yaml").is_file() and (out / "metrics.jsonl").is_file():  # a training run
        return "mvsformerpp train"
    return None


def _marker(out: Path) -> dict | None:
    try:
        record = json.loads((out / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def check_owned(out: Path, kind: str, reuse: bool = True, flag: str = "-o") -> None:
    """Refuse an existing non-empty folder unless ``reuse`` and an earlier run of ``kind`` wrote it."""
    if not os.path.lexists(out):
        return
    if not out.is_dir():
        raise InputError(f"the output path exists and is not a folder; choose another {flag}", out)
    entries = [p.name for p in out.iterdir() if p.name not in (LOCK, MARKER)]
    if not entries or (reuse and written_by(out) == f"mvsformerpp {kind}"):
        return
    shown = ", ".join(sorted(entries)[:4]) + (" ..." if len(entries) > 4 else "")
    whose = "" if reuse else " (it must be new or empty)"
    raise InputError(f"the output folder is not empty and was not written by mvsformerpp {kind}{whose}: it holds "
                     f"{shown}. Choose a new or empty folder so that no file of yours is overwritten", out)


def _check_settings(out: Path, kind: str, settings: dict) -> None:
    """An earlier run of ``kind`` in ``out`` must have had ``settings`` (a rerun completes it, never mixes)."""
    recorded = (_marker(out) or {}).get("settings")
    entries = [p for p in out.iterdir() if p.name not in (LOCK, MARKER) and not _TEMPORARY.match(p.name)]
    if not entries:
        return
    if not isinstance(recorded, dict):
        raise InputError(f"the output folder holds an earlier mvsformerpp {kind} output whose settings are not "
                         "recorded; choose a new folder (or delete this one to start over)", out)
    # A setting the record lacks was added after that run was written: its None keeps the earlier behaviour.
    diffs = [f"{k} {recorded.get(k)!r} -> {v!r}" for k, v in settings.items() if recorded.get(k) != v]
    diffs += [f"{k} {recorded[k]!r} -> (none)" for k in recorded if k not in settings]
    if not diffs:
        return
    raise InputError(f"the output folder holds mvsformerpp {kind} output of other settings ({'; '.join(diffs)}); "
                     "run with the same settings to complete it, or choose a new folder", out)


def remove_temporaries(folder: Path) -> int:
    """Delete the ``.NAME.XXXX.tmp`` / ``.NAME.link`` files and staged folders an interrupted run left in
    ``folder`` (a folder of this package's); returns how many."""
    removed = 0
    for dirpath, dirs, files in os.walk(folder):
        for name in [d for d in dirs if _TEMPORARY.match(d)]:
            dirs.remove(name)
            shutil.rmtree(os.path.join(dirpath, name), ignore_errors=True)
            removed += 1
        for name in files:
            if _TEMPORARY.match(name):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(os.path.join(dirpath, name))
                    removed += 1
    return removed


def folder_lock(folder: Path) -> contextlib.AbstractContextManager[None]:
    """Hold the lock of a run folder for the block; :class:`FolderBusyError` if another run holds it."""
    return hold_lock(Path(folder) / LOCK, Path(folder))


def check_output_folder(out: str | Path, inputs: Sequence[str | Path] = (), kind: str = "reconstruct",
                        reuse: bool = True, flag: str = "-o") -> Path:
    """The checks of :func:`claim_output_folder` that need no lock: for commands that check their output before
    minutes of work and claim it when they start writing."""
    out = check_output_path(out, flag)
    check_not_input(out, inputs, flag)
    check_owned(out, kind, reuse, flag)
    return out


@contextlib.contextmanager
def claim_output_folder(out: str | Path, inputs: Sequence[str | Path] = (), kind: str = "reconstruct",
                        reuse: bool = True, settings: dict | None = None, flag: str = "-o") -> Iterator[Path]:
    """Check, create and lock the folder ``out`` for one run of ``kind`` (see the module docstring); yields it.

    ``inputs``: folders and files the run reads (the folder must not overlap them). ``reuse``: an earlier
    output of the same ``kind`` may be continued (resumable commands); False accepts only a new or empty
    folder. ``settings``: recorded in the marker when the folder is new; a later run must bring the same ones
    (it completes the output instead of mixing two).
    """
    out = check_output_folder(out, inputs, kind, reuse, flag)
    created = not os.path.lexists(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create the output folder ({e.strerror}); choose another {flag}", out) from e
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError("the output folder is not writable (permission denied or a read-only file system); "
                         f"choose another {flag}", out)
    rank, world = env_rank().rank, env_rank().world_size
    # One job of several processes (torchrun): rank 0 holds the lock for all of them, and nobody removes
    # temporaries, which may be another rank's file in flight.
    held = contextlib.ExitStack()
    try:
        if rank == 0:
            held.enter_context(folder_lock(out))
            if settings is not None:
                settings = json.loads(json.dumps(settings))  # as the marker will read back (tuples as lists)
                _check_settings(out, kind, settings)
            record = {"written_by": f"mvsformerpp {kind}", **({"settings": settings} if settings is not None else {})}
            if _marker(out) != record:
                (out / MARKER).write_text(json.dumps(record) + "\n")
        if world == 1:
            remove_temporaries(out)
    except BaseException as e:
        held.close()
        if created:
            _remove_if_unused(out)
        if isinstance(e, OSError) and e.errno in (errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC):
            raise InputError(f"cannot write to the output folder ({e.strerror}); choose another {flag}", out) from e
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


def check_replaceable(path: str | Path, kind: FileKind, flag: str = "-o", run: str | Path | None = None) -> None:
    """Refuse to write ``path`` unless it is new or a file of ``kind`` that this package wrote. In a run folder of
    this package, a name that belongs to a kind (``fused.ply``, ``report.html``) is refused even when new, unless
    the writer makes that kind for that very folder (``run``: the folder it works on)."""
    path = Path(path)
    if written_by(path.parent) is not None:
        owner = next((k for k in KINDS if k.run_name == path.name), None)
        if owner is not None and owner.what != kind.what:
            raise InputError(f"{path.name} is the run's own {owner.what}; write the {kind.what} under another name "
                             f"(choose another {flag})", path)
        if owner is not None and (run is None or Path(run).resolve() != path.parent.resolve()):
            raise InputError(f"{path.name} is the own {owner.what} of the run in {path.parent}, not of the one this "
                             f"command reads; choose another {flag}", path)
    if not path.exists():
        return
    if not path.is_file():
        raise InputError(f"the output exists and is not a file; choose another {flag} for the {kind.what}", path)
    if not kind.has_format(path):
        raise InputError(f"the output exists and is not {_article(kind.what)} {kind.what} file; choose another "
                         f"{flag} so that it is not overwritten", path)
    if not kind.written_here(path):
        raise InputError(f"the output exists and is a file that mvsformerpp did not write as {_article(kind.what)} "
                         f"{kind.what} (yours, or another command's); choose another {flag} so that it is not "
                         "overwritten, or delete it first", path)


def _article(what: str) -> str:
    """"a" or "an" before ``what``: by its first letter's sound (acronyms spelt out: an HTML, an SVG)."""
    first = what[:1]
    return "an" if (first in "AEFHILMNORSX" if first.isupper() else first in "aeiou") else "a"


def check_output_file(path: str | Path, kind: FileKind, inputs: Sequence[str | Path] = (), flag: str = "-o",
                      run: str | Path | None = None) -> Path:
    """Every check of :func:`claim_output_file` but the lock: for commands that check their outputs before
    minutes of work and claim them when they write."""
    path = check_output_path(path, flag, room=TEMPORARY_ROOM)
    check_not_input_file(path, inputs, flag)
    check_replaceable(path, kind, flag, run)
    return path


@contextlib.contextmanager
def claim_output_file(path: str | Path, kind: FileKind, inputs: Sequence[str | Path] = (),
                      flag: str = "-o", run: str | Path | None = None) -> Iterator[Path]:
    """Check that ``path`` may be written as a file of ``kind`` (see the module docstring), then hold it for the block.

    In a folder of this package's, the folder's lock is held (fusing into a folder that another
    ``reconstruct`` writes stops with the holder's name; a claim by the run that holds it in this process
    shares its hold); elsewhere ``.NAME.lock`` beside the file. The temporaries that a killed run left for
    this name are removed; errors of a full disk or a read-only place name the output (:func:`writing`).
    ``inputs``: files and folders the writer reads; ``run``: the run folder it works on (:func:`check_replaceable`).
    """
    path = check_output_file(path, kind, inputs, flag, run)
    folder = path.parent
    made = make_folders(folder, flag)
    try:
        if os.path.realpath(folder) in HELD:
            lock = contextlib.nullcontext()
        elif written_by(folder) is not None:
            lock = folder_lock(folder)
        else:
            lock = hold_lock(folder / f".{path.name}.lock", path, "file", remove=True)
        with lock:
            for p in folder.glob(f".{glob_escape(path.name)}.*.tmp"):
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
            with writing(path):
                yield path
    except BaseException:
        for d in reversed(made):  # folders this claim made and nothing filled
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


def make_folders(folder: Path, flag: str) -> list[Path]:
    """Create ``folder`` and its missing parents; returns those it created, outermost first."""
    missing = []
    here = folder.absolute()
    while not os.path.lexists(here):
        missing.append(here)
        here = here.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create the output's folder ({e.strerror}); choose another {flag}", folder) from e
    return missing[::-1]


def child(folder: Path, name: str, what: str) -> Path:
    """``folder / name`` for a ``name`` made from data (a scene or view name, ``what``), refused when it would
    lie outside ``folder`` or is no name at all."""
    target = Path(folder) / name
    if not name or name.startswith(".") or os.path.isabs(name) or ".." in Path(name).parts or \
            not _inside(target.resolve(), Path(folder).resolve()) or target.resolve() == Path(folder).resolve():
        raise InputError(f"{what} {name!r} would not be a file inside {folder}; use a plain name (no '..', no "
                         "leading '.' or '/')")
    return target


@contextlib.contextmanager
def writing(path: str | Path, staged: Path | None = None, what: str = "file") -> Iterator[None]:
    """Turn a full disk, a denied permission or a read-only file system while writing ``path`` (its temporary, or
    a file inside the folder ``staged`` that becomes ``path``) into an :class:`InputError` that names ``path``;
    errors about other files pass unchanged."""
    try:
        yield
    except OSError as e:
        if e.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR,
                           errno.ENAMETOOLONG):
            raise
        target = Path(path).absolute()
        where = None if e.filename is None else Path(os.fsdecode(e.filename)).absolute()
        ours = where is None or (where.parent == target.parent and (where.name == target.name or where.name.startswith(
            f".{target.name}."))) or (staged is not None and _inside(where, Path(staged).absolute()))
        if not ours:
            raise
        advice = ("free some space and run the command again" if e.errno in (errno.ENOSPC, errno.EDQUOT)
                  else "choose a location you can write to")
        raise InputError(f"cannot write this {what} ({e.strerror}); {advice}. Files written before are kept",
                         path) from e


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)
