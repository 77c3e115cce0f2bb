"""Text files of the scene formats: read with one clear error per failure, floats written exactly."""

from __future__ import annotations

from pathlib import Path

from mvsformerpp.errors import FormatError, InputError


def read_text(path: Path, kind: str, not_text: str | None = None) -> str:
    """The UTF-8 text of ``path`` (a byte-order mark dropped).

    InputError when it does not exist, FormatError when it cannot be read or is not text; the messages
    call it ``kind`` (``"pair file"``), ``not_text`` replaces the one for a file that is not text.
    """
    try:
        return path.read_bytes().decode("utf-8-sig")
    except FileNotFoundError as e:
        raise InputError(f"{kind} not found", path) from e
    except OSError as e:
        raise FormatError(f"cannot read {kind} ({e.strerror})", path) from e
    except UnicodeDecodeError as e:
        raise FormatError(not_text or f"{kind} is not text", path) from e


def format_float(x: float) -> str:
    """Shortest text that reads back as exactly the same float."""
    return repr(float(x))
