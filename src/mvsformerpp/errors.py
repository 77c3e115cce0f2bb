"""Exceptions that reach the user: each message says what is wrong and how to fix it."""

from __future__ import annotations

from pathlib import Path


class MVSFormerError(Exception):
    """Base class: the CLI prints these as one clear message and exits non-zero."""


class InputError(MVSFormerError):
    """Bad user input (a file, a folder, an argument)."""

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = Path(path) if path is not None else None
        super().__init__(f"{path}: {message}" if path is not None else message)


class FormatError(InputError):
    """A file exists but its content does not follow the format it claims."""


class MissingDependencyError(MVSFormerError):
    """An optional dependency is needed for this feature."""

    def __init__(self, module: str, extra: str, feature: str):
        super().__init__(
            f"{feature} needs the optional package '{module}'. "
            f"Install it with: pip install 'mvsformerpp[{extra}]'"
        )
