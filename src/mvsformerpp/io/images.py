"""Photos: decode to RGB uint8, or read only the size from the file header.

Arrays are ``[H, W, 3]`` uint8, RGB, top row first. Grayscale, palette, 16-bit, 32-bit float and RGBA/LA
images are converted (alpha is dropped, not composited; :func:`read_alpha` reads it). Float images hold
intensities in [0, 1] (the usual convention of float TIFF and of image libraries) or, when their values
exceed 1, in [0, 255] or their own range.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError

# Suffixes recognised as photos when a layout looks images up by stem (lower case).
IMAGE_SUFFIXES: tuple[str, ...] = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")


def _open(path: Path):
    from PIL import Image, UnidentifiedImageError

    try:
        return Image.open(path)
    except Image.DecompressionBombError as e:
        raise FormatError(f"image is too large to decode safely ({e}); downscale it first", path) from e
    except FileNotFoundError as e:
        raise FormatError("image file not found", path) from e
    except UnidentifiedImageError as e:
        raise FormatError("not a readable image (unknown or corrupt format)", path) from e
    except OSError as e:
        raise FormatError(f"cannot open image ({e})", path) from e


def image_size(path: str | Path) -> tuple[int, int]:
    """Return ``(width, height)`` from the file header, without decoding the pixels."""
    path = Path(path)
    with _open(path) as im:
        return int(im.width), int(im.height)


def read_image(path: str | Path) -> np.ndarray:
    """Decode an image file to uint8 ``[H, W, 3]`` RGB."""
    path = Path(path)
    with _open(path) as im:
        try:
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                # 16/32-bit grayscale: rescale the full range to 8 bits rather than clip.
                arr = np.asarray(im, dtype=np.float64)
                hi = 65535.0 if im.mode.startswith("I;16") else max(float(arr.max()), 1.0)
                gray = np.clip(np.round(arr / hi * 255.0), 0, 255).astype(np.uint8)
                return np.ascontiguousarray(np.repeat(gray[:, :, None], 3, axis=2))
            if im.mode == "F":
                return _float_to_rgb(np.asarray(im, dtype=np.float64), path)
            rgb = im.convert("RGB")
            return np.asarray(rgb, dtype=np.uint8).copy()
        except (OSError, ValueError, SyntaxError) as e:
            raise FormatError(f"cannot decode image ({e}); the file may be truncated or corrupt", path) from e


def _float_to_rgb(arr: np.ndarray, path: Path) -> np.ndarray:
    finite = np.isfinite(arr)
    if not finite.any():
        raise FormatError("float image holds no finite value (all NaN or infinite)", path)
    lo, hi = float(arr[finite].min()), float(arr[finite].max())
    if hi <= 1.0 + 1e-6:  # [0, 1] (small negative values from processing are clipped)
        scale, offset = 255.0, 0.0
    elif lo >= 0 and hi <= 255.0:  # already 8-bit values
        scale, offset = 1.0, 0.0
    else:  # some other range: stretched to 8 bits
        scale, offset = 255.0 / (hi - lo), lo
    gray = np.clip(np.round((np.where(finite, arr, lo) - offset) * scale), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(np.repeat(gray[:, :, None], 3, axis=2))


def read_alpha(path: str | Path) -> np.ndarray | None:
    """The alpha channel of an image file as uint8 ``[H, W]``, or None when it has none (or it is opaque
    everywhere: then it says nothing)."""
    path = Path(path)
    with _open(path) as im:
        try:
            if im.mode == "P" and "transparency" in im.info:
                im = im.convert("RGBA")
            if im.mode not in ("RGBA", "LA", "PA", "RGBa", "La"):
                return None
            alpha = np.asarray(im.getchannel("A"), dtype=np.uint8).copy()
        except (OSError, ValueError, SyntaxError) as e:
            raise FormatError(f"cannot decode image ({e}); the file may be truncated or corrupt", path) from e
    return None if alpha.min() == 255 else alpha


def find_image(folder: str | Path, stem: str) -> Path | None:
    """Return the photo ``folder/stem.<ext>`` for a known image suffix (any case), or None."""
    folder = Path(folder)
    for suffix in IMAGE_SUFFIXES:
        for cand in (folder / f"{stem}{suffix}", folder / f"{stem}{suffix.upper()}"):
            if cand.is_file():
                return cand
    return None


def list_images(folder: str | Path) -> list[Path]:
    """Photos directly inside ``folder`` (by suffix), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
