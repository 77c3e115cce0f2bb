"""The ``mvsformerpp`` command: one subcommand per module in this package.

Each subcommand module defines ``register(subparsers)``, which adds its parser and sets
``func`` to a callable taking the parsed arguments and returning an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from mvsformerpp.errors import MVSFormerError

# Subcommand modules, in the order `--help` lists them.
COMMANDS: tuple[str, ...] = ("demo", "reconstruct", "fuse", "evaluate", "info", "synth", "train")


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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except MVSFormerError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted; run the same command again to continue where it stopped", file=sys.stderr)
        return 130


def entry() -> int:
    """The console script: tune the allocator for large tensors (see utils.allocator), then run."""
    from mvsformerpp.utils.allocator import tune_allocator

    tune_allocator()
    return main()


if __name__ == "__main__":
    sys.exit(entry())
