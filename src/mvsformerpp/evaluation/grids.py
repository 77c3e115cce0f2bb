"""Depth maps on a grid ``step`` times coarser and back, in the integer-pixel convention of MVSNet-style
cams: coarse pixel j lies on fine pixel ``step`` x j (as the training pipeline's ``depth[::4, ::4]``), not
at the centre of its ``step`` x ``step`` block."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates


def on_coarse_grid(depth: np.ndarray, shape: tuple[int, int], step: int) -> np.ndarray:
    """``depth`` at the pixels of a grid ``step`` times coarser of ``shape`` (h, w): the median of each such
    pixel's 3x3 neighbourhood (edges repeated)."""
    h, w = shape
    padded = np.pad(depth[: step * h, : step * w], 1, mode="edge")
    near = [padded[1 + dy: 1 + dy + step * h: step, 1 + dx: 1 + dx + step * w: step]
            for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    return np.median(np.stack(near, -1), -1)


def from_coarse_grid(coarse: np.ndarray, step: int, order: int = 0) -> np.ndarray:
    """A map ``step`` times finer whose pixel ``step`` x j holds coarse pixel j (:func:`on_coarse_grid`'s
    convention), the pixels between from the nearest coarse pixel (``order`` 0) or linearly (1); where a
    linear value would mix in a coarse 0 (no data) it is 0."""
    h, w = coarse.shape
    ys, xs = np.mgrid[0 : step * h, 0 : step * w] / step
    coords = np.stack([ys, xs])
    out = map_coordinates(coarse.astype(np.float64), coords, order=order, mode="nearest")
    if order:
        full = map_coordinates((coarse > 0).astype(np.float64), coords, order=order, mode="nearest")
        out = np.where(full > 0.999, out, 0.0)
    return out.astype(np.float32)
