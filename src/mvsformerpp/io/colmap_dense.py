"""COLMAP's dense-workspace arrays: ``stereo/depth_maps/*.bin`` and ``stereo/normal_maps/*.bin``.

Format (COLMAP ``mvs/mat.h``): an ASCII header ``width&height&channels&`` followed by float32
little-endian values, channel after channel, each channel row after row (the reading order of
``np.fromfile(...).reshape((width, height, channels), order="F")`` in COLMAP's own script).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError
from mvsformerpp.utils.atomic import atomic_open


def write_colmap_array(path: str | Path, array: np.ndarray) -> None:
    """Write ``[H, W]`` or ``[H, W, C]`` as a COLMAP array file (atomically)."""
    a = np.asarray(array, dtype="<f4")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3:
        raise ValueError(f"COLMAP arrays are [H, W] or [H, W, C], got {a.shape}")
    h, w, c = a.shape
    with atomic_open(path, "wb") as f:
        f.write(f"{w}&{h}&{c}&".encode("ascii"))
        f.write(np.ascontiguousarray(a.transpose(2, 0, 1)).tobytes())


def read_colmap_array(path: str | Path) -> np.ndarray:
    """Read a COLMAP array file as ``[H, W]`` (one channel) or ``[H, W, C]`` float32."""
    path = Path(path)
    raw = path.read_bytes()
    parts = raw.split(b"&", 3)
    try:
        w, h, c = (int(x) for x in parts[:3])
    except ValueError as e:
        raise FormatError("not a COLMAP array file (header width&height&channels&)", path) from e
    data = parts[3] if len(parts) > 3 else b""
    if len(data) != 4 * w * h * c:
        raise FormatError(f"COLMAP array announces {w}x{h}x{c} values but holds {len(data) // 4}", path)
    a = np.frombuffer(data, dtype="<f4").reshape(c, h, w).transpose(1, 2, 0)
    return a[..., 0].copy() if c == 1 else a.copy()
