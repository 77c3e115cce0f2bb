"""Folders written as a whole and put in place by renames (``export``'s workspace), under the output guard.

The new folder is built beside the target under a temporary name (``.NAME.XXXXXXXX.tmp``, which holds the
package's marker from its start). Once it is complete, the old target (if any) is renamed aside
(``.NAME.previous``), the new one renamed in, and the old one deleted: the old folder goes only once the
new one is in place. A run killed at any instant leaves the old folder or the new one under the target's
name, or the old one aside and no target; the next run over the same target puts the old one back in
the last case, deletes an aside whose replacement is in place, and removes the staged folders of killed
runs. The folder gets the permissions a plain ``mkdir`` would give it.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from mvsformerpp.errors import InputError
from mvsformerpp.utils.atomic import current_umask
from mvsformerpp.utils.interrupts import deferred_interrupt
from mvsformerpp.utils.locks import hold_lock
from mvsformerpp.utils.output_guard import (
    MARKER,
    TEMPORARY_ROOM,
    check_not_input,
    check_output_path,
    glob_escape,
    make_folders,
    writing,
    written_by,
)


def _aside(target: Path) -> Path:
    return target.parent / f".{target.name}.previous"


@contextlib.contextmanager
def claim_output_tree(target: str | Path, kind: str, inputs: Sequence[str | Path] = (), overwrite: bool = False,
                      recognise: Callable[[Path], bool] | None = None, flag: str = "DIR",
                      overwrite_flag: str = "--overwrite") -> Iterator[Path]:
    """Yield an empty staging folder that replaces the folder ``target`` once the block ends without error.

    ``target`` must be new, empty, or (with ``overwrite``) a folder that ``mvsformerpp kind`` wrote (its
    marker) or that ``recognise`` accepts (an earlier version's output); it must not overlap ``inputs`` nor
    be a symbolic link. The target's name is locked for the block (``.NAME.lock`` beside it).
    """
    target = check_output_path(target, flag, room=TEMPORARY_ROOM)
    if target.is_symlink():
        raise InputError(f"the output is a symbolic link; give the folder it points to, or choose another {flag}",
                         target)
    check_not_input(target, inputs, flag)
    parent = target.parent
    made = make_folders(parent, flag)

    def owned(path: Path) -> bool:
        return written_by(path) == f"mvsformerpp {kind}" or (recognise is not None and recognise(path))

    try:
        with hold_lock(parent / f".{target.name}.lock", target, "folder", remove=True):
            _recover(target, kind, owned)
            _check_replaceable(target, owned, overwrite, flag, overwrite_flag, kind)
            with writing(target, what="folder"):
                staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent))
            try:
                with writing(target, staged=staging, what="folder"):
                    os.chmod(staging, 0o777 & ~current_umask())
                    (staging / MARKER).write_text(json.dumps({"written_by": f"mvsformerpp {kind}"}) + "\n")
                    yield staging
                    with deferred_interrupt():
                        _swap(staging, target)
            except BaseException:
                shutil.rmtree(staging, ignore_errors=True)
                raise
    except BaseException:
        for d in reversed(made):  # folders made for a target that did not come
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


def _check_replaceable(target: Path, owned: Callable[[Path], bool], overwrite: bool, flag: str, overwrite_flag: str,
                       kind: str) -> None:
    if not os.path.lexists(target):
        return
    if not target.is_dir():
        raise InputError(f"the output exists and is not a folder; choose another {flag}", target)
    if any(target.iterdir()):
        if not overwrite:
            raise InputError(f"the output folder exists and is not empty; choose another {flag} or pass "
                             f"{overwrite_flag}", target)
        if not owned(target):
            raise InputError(f"{overwrite_flag} replaces only an empty folder or one that mvsformerpp {kind} wrote, "
                             f"and this is neither; choose another {flag}", target)


def _swap(staging: Path, target: Path) -> None:
    aside = _aside(target)
    if os.path.lexists(target):
        os.rename(target, aside)
    os.rename(staging, target)
    shutil.rmtree(aside, ignore_errors=True)


def _recover(target: Path, kind: str, owned: Callable[[Path], bool]) -> None:
    """Finish or undo the swap of a killed run, and remove its staged folders."""
    aside = _aside(target)
    if aside.is_dir() and not aside.is_symlink() and (owned(aside) or not any(aside.iterdir())):
        if os.path.lexists(target):
            shutil.rmtree(aside)
        else:
            os.rename(aside, target)
    for p in target.parent.glob(f".{glob_escape(target.name)}.*.tmp"):
        if p.is_dir() and not p.is_symlink() and written_by(p) == f"mvsformerpp {kind}":
            shutil.rmtree(p, ignore_errors=True)
