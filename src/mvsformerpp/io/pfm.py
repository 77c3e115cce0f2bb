"""PFM (portable float map): ``Pf`` (1 channel) and ``PF`` (3 channels), either endianness.

Rows are stored bottom-up in the file; arrays in memory are top-down, as images are.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError
from mvsformerpp.utils.atomic import atomic_open

# Header: three whitespace-separated tokens (type, "W H", scale), each line ended by one newline.
_HEADER = re.compile(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s")


def pfm_shape(path: str | Path) -> tuple[int, ...]:
    """The array shape a PFM file holds, ``(H, W)`` or ``(H, W, 3)``, from its header alone."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(256)
    except OSError as e:
        raise FormatError(f"cannot read PFM file ({e.strerror})", path) from e
    m = _HEADER.match(head)
    if m is None:
        raise FormatError("not a PFM file (expected a 'Pf' or 'PF' header, width, height and scale)", path)
    width, height = int(m.group(2)), int(m.group(3))
    return (height, width, 3) if m.group(1) == b"PF" else (height, width)


def read_pfm(path: str | Path) -> np.ndarray:
    """Read a PFM file as float32 [H, W] (``Pf``) or [H, W, 3] (``PF``), top row first."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise FormatError(f"cannot read PFM file ({e.strerror})", path) from e
    m = _HEADER.match(data)
    if m is None:
        raise FormatError("not a PFM file (expected a 'Pf' or 'PF' header, width, height and scale)", path)
    channels = 3 if m.group(1) == b"PF" else 1
    width, height = int(m.group(2)), int(m.group(3))
    try:
        scale = float(m.group(4))
    except ValueError as e:
        raise FormatError(f"bad PFM scale {m.group(4)!r}", path) from e
    if scale == 0:
        raise FormatError("PFM scale is 0 (its sign gives the endianness and must be non-zero)", path)
    dtype = np.dtype("<f4") if scale < 0 else np.dtype(">f4")
    count = width * height * channels
    body = data[m.end():]
    if len(body) < count * 4:
        raise FormatError(
            f"PFM file is truncated: {width}x{height}x{channels} needs {count * 4} bytes of data, "
            f"found {len(body)}",
            path,
        )
    arr = np.frombuffer(body, dtype=dtype, count=count).astype(np.float32)
    shape = (height, width, 3) if channels == 3 else (height, width)
    return np.ascontiguousarray(np.flipud(arr.reshape(shape)))


def write_pfm(path: str | Path, array: np.ndarray) -> None:
    """Write float [H, W] or [H, W, 3] as little-endian PFM, atomically."""
    arr = np.asarray(array, dtype=np.float32)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim == 2:
        kind = b"Pf"
    elif arr.ndim == 3 and arr.shape[2] == 3:
        kind = b"PF"
    else:
        raise ValueError(f"PFM holds [H,W] or [H,W,3] arrays, got shape {arr.shape}")
    h, w = arr.shape[:2]
    header = kind + b"\n" + f"{w} {h}\n-1.0\n".encode()
    with atomic_open(path, "wb") as f:
        f.write(header)
        f.write(np.flipud(arr).astype("<f4").tobytes())
