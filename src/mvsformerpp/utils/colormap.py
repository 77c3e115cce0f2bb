"""Colour maps for depth and confidence previews (PNG), without matplotlib.

The map is the perceptually ordered "turbo" rainbow, given here by its published polynomial
approximation (Mikhailov 2019) so that no plotting library is needed.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from mvsformerpp.utils.atomic import atomic_open

# Degree-5 polynomial fit of turbo per channel, coefficients c0..c5 (Mikhailov, Google AI blog 2019).
_TURBO = np.array(
    [
        [0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
        [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
        [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973],
    ]
)


_LEVELS = 4096  # table entries: neighbouring entries differ by at most one level of a channel


@functools.cache
def _turbo_table() -> np.ndarray:
    x = np.linspace(0.0, 1.0, _LEVELS)
    rgb = np.clip((x[:, None] ** np.arange(6)) @ _TURBO.T, 0.0, 1.0)
    return (rgb * 255.0 + 0.5).astype(np.uint8)


def turbo(x: np.ndarray) -> np.ndarray:
    """Map values in [0, 1] (clipped; NaN as 0) to RGB uint8 ``[..., 3]``: the polynomial tabulated at
    4096 levels (a preview's pixels are coloured by lookup, about three times faster than evaluating it)."""
    x = np.nan_to_num(np.asarray(x, dtype=np.float32), nan=0.0)
    index = np.rint(np.clip(x, 0.0, 1.0) * np.float32(_LEVELS - 1)).astype(np.intp)
    return _turbo_table()[index]


def colorize(values: np.ndarray, vmin: float | None = None, vmax: float | None = None,
             invalid: np.ndarray | None = None) -> np.ndarray:
    """Colour-map a 2-D array to RGB uint8 ``[H, W, 3]``; ``invalid`` pixels (and non-finite ones) are black.

    ``vmin``/``vmax`` default to the 2nd/98th percentiles of the valid values (robust to outliers).
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"colorize expects a 2-D array, got shape {v.shape}")
    bad = ~np.isfinite(v)
    if invalid is not None:
        bad |= np.asarray(invalid, dtype=bool)
    good = v[~bad]
    if vmin is None or vmax is None:
        lo, hi = (np.percentile(good, [2.0, 98.0]) if good.size else (0.0, 1.0))
        vmin = lo if vmin is None else vmin
        vmax = hi if vmax is None else vmax
    span = vmax - vmin if vmax > vmin else 1.0
    rgb = turbo((np.where(bad, vmin, v) - vmin) / span)
    rgb[bad] = 0
    return rgb


def kept_pixels(depth: np.ndarray, confidence: np.ndarray | None = None,
                threshold: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(pixels with a depth, those of them fusion keeps by confidence: above ``threshold``; all with a depth
    when there is no confidence or no threshold)."""
    depth = np.asarray(depth)
    valid = np.isfinite(depth) & (depth > 0)
    if confidence is None or threshold is None:
        return valid, valid
    return valid, valid & (np.nan_to_num(np.asarray(confidence), nan=-1.0) > threshold)


def depth_scale(depth: np.ndarray, kept: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """The colour range of a depth preview: 2nd-98th percentile of the kept pixels (else of all with a
    depth), so that what fusion drops (sky, a black background) does not stretch the scale."""
    ref = kept if kept.any() else valid
    if not ref.any():
        return 0.0, 1.0
    lo, hi = np.percentile(np.asarray(depth)[ref], [2.0, 98.0])
    return float(lo), float(hi) if hi > lo else float(lo) + 1e-6


def depth_colors(depth: np.ndarray, confidence: np.ndarray | None = None, threshold: float | None = None,
                 scale: tuple[float, float] | None = None) -> np.ndarray:
    """RGB uint8 ``[H, W, 3]`` of a depth map as fusion sees it: the pixels it keeps in colour (near = blue,
    far = red, over ``scale``, default :func:`depth_scale`), the pixels its confidence threshold drops in
    grey (their shading still shows the shape), pixels without depth black."""
    valid, kept = kept_pixels(depth, confidence, threshold)
    lo, hi = scale if scale is not None else depth_scale(depth, kept, valid)
    rgb = colorize(np.where(valid, depth, lo), lo, hi, invalid=~valid)
    dropped = valid & ~kept
    if dropped.any():
        luma = rgb[dropped].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
        rgb[dropped] = np.round(60.0 + 0.35 * luma).astype(np.uint8)[:, None]
    return rgb


def depth_to_png(path: str | Path, depth: np.ndarray, confidence: np.ndarray | None = None,
                 threshold: float | None = None) -> None:
    """Write a depth preview (:func:`depth_colors`: what fusion keeps in colour, what it drops grey)."""
    save_png(path, depth_colors(depth, confidence, threshold))


def confidence_to_png(path: str | Path, confidence: np.ndarray) -> None:
    """Write a colour-mapped confidence preview on the fixed scale [0, 1]."""
    save_png(path, colorize(confidence, 0.0, 1.0))


def save_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write RGB uint8 ``[H, W, 3]`` as PNG, atomically. zlib level 1 with run-length matching: previews
    are written once per view while the network runs, and this encodes them 3-4 times faster than the
    default (level 6) for files a fifth larger (run-length matching: 12-16 % smaller and a little faster
    than level 1's default strategy on depth and confidence previews)."""
    import zlib

    from PIL import Image

    with atomic_open(path, "wb") as f:
        Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8), mode="RGB").save(
            f, format="PNG", compress_level=1, compress_type=zlib.Z_RLE)
