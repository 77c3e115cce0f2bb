"""The ``mvsformerpp`` command: one subcommand per module in this package.

Each subcommand module defines ``register(subparsers)``, which adds its parser and sets
``func`` to a callable taking the parsed arguments and returning an exit code; optionally ``on_interrupt``
(how to continue after Ctrl-C) and ``on_memory_error`` (the settings that need less memory). A subcommand
imports its pipeline inside that callable, not at the top of its module: every invocation builds the whole
parser, which loads neither torch nor scipy (``tests/cli/test_startup.py``; torch alone takes seconds).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import sys

from mvsformerpp.errors import MVSFormerError

# Subcommand modules, in the order `--help` lists them.
COMMANDS: tuple[str, ...] = ("demo", "reconstruct", "fuse", "mesh", "export", "export_onnx", "report", "view",
                             "evaluate", "info", "synth", "textures", "train")


# Operating-system errors the user fixes (space, permissions, read-only media, a path under a file).
_USER_FIXABLE = {errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOTDIR, errno.EISDIR,
                 errno.ENAMETOOLONG}


def _one_line(message: str) -> str:
    return " ".join(message.split("\n")).strip()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mvsformerpp",
        description="MVSFormer++ multi-view stereo: depth maps and fused point clouds from calibrated photos.",
    )
    from mvsformerpp import __version__

    parser.add_argument("--version", action="version", version=f"mvsformerpp {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"mvsformerpp.cli.{name}").register(sub)
    return parser


class _WarningLines(logging.Handler):
    """The package's warnings as ``warning: ...`` lines on the current stderr."""

    def emit(self, record: logging.LogRecord) -> None:
        print(f"warning: {_one_line(record.getMessage())}", file=sys.stderr)


def _show_warnings() -> None:
    logger = logging.getLogger("mvsformerpp")
    if not any(isinstance(h, _WarningLines) for h in logger.handlers):
        logger.addHandler(_WarningLines(logging.WARNING))


def _print_any_name() -> None:
    """File names may hold bytes that are not UTF-8 (Python reads them as surrogates): print them back as
    those bytes instead of failing after the work is done."""
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="surrogateescape")


def main(argv: list[str] | None = None) -> int:
    _show_warnings()
    _print_any_name()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except MVSFormerError as e:
        print(f"error: {_one_line(str(e))}", file=sys.stderr)
        return 2
    except OSError as e:
        if e.errno not in _USER_FIXABLE:
            raise
        where = f"{e.filename}: " if e.filename else ""
        if e.errno == errno.ENAMETOOLONG and e.filename:
            where = f"{_shortened(e.filename)}: "
        advice = {errno.ENOSPC: "free some space and run the same command again",
                  errno.EDQUOT: "free some space and run the same command again",
                  errno.EROFS: "the file system is read-only: choose another location",
                  errno.ENAMETOOLONG: "a name in the path is longer than the file system allows (usually 255 "
                                      "bytes): choose a shorter one"}.get(e.errno, "check the path and its permissions")
        print(f"error: {where}{e.strerror}; {advice} (finished outputs are kept)", file=sys.stderr)
        return 2
    except MemoryError:
        advice = getattr(args, "on_memory_error", "use smaller inputs or settings")
        print(f"error: out of memory; {advice}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        advice = getattr(args, "on_interrupt", "run the same command again to continue where it stopped")
        print(f"interrupted; {advice}", file=sys.stderr)
        return 130


def _shortened(name: str | bytes, keep: int = 20) -> str:
    """A path with each over-long name cut to its first ``keep`` characters."""
    name = name if isinstance(name, str) else name.decode(errors="surrogateescape")
    return "/".join(part if len(part) <= 2 * keep else f"{part[:keep]}..." for part in name.split("/"))


def entry() -> int:
    """The console script: tune the allocator for large tensors (see utils.allocator), then run."""
    from mvsformerpp.utils.allocator import tune_allocator

    tune_allocator()
    return main()


if __name__ == "__main__":
    sys.exit(entry())
