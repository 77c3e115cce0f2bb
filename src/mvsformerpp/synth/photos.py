"""Natural-image textures for synthetic scenes: the sample photographs inside the scikit-image wheel.

scikit-image (the ``train`` extra) ships a few dozen sample photographs in ``skimage/data`` (astronaut,
coffee, brick, grass, gravel, a cat, a rocket, ...). They are read straight from that folder with
Pillow: nothing is imported from scikit-image and nothing is downloaded. Without scikit-image the
textures are procedural 2-D images instead (coloured fractal noise, cells, stripes), so the generator
works everywhere; :func:`texture_source` says which set is in use. A texture library of real photographs
(:mod:`mvsformerpp.synth.texture_library`) replaces both where a recipe names one
(``synthetic_options: {textures: LIBRARY}``).

A texture is a mip pyramid of uint8 RGB images (each level half the previous), sampled with mirrored
repetition (no seams) and bilinear interpolation at the level whose texel matches the pixel footprint.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image

from mvsformerpp.synth.mipmaps import pyramid
from mvsformerpp.synth.texture_library import TextureLibrary

# Photographs of ordinary scenes and materials in scikit-image's wheel (no charts, faces, or scans).
SKIMAGE_PHOTOS = ("astronaut.png", "brick.png", "camera.png", "chelsea.png", "coffee.png", "grass.png",
                  "gravel.png", "rocket.jpg", "motorcycle_left.png", "motorcycle_right.png", "coins.png",
                  "moon.png", "page.png", "text.png", "color.png", "hubble_deep_field.jpg", "retina.jpg",
                  "ihc.png", "cell.png", "clock_motion.png", "logo.png", "horse.png")


def skimage_data_dir() -> Path | None:
    """Folder of scikit-image's bundled sample data, or None when scikit-image is not installed."""
    spec = importlib.util.find_spec("skimage")
    if spec is None or spec.origin is None:
        return None
    folder = Path(spec.origin).parent / "data"
    return folder if folder.is_dir() else None


def procedural_images(count: int = 16, size: int = 256, seed: int = 1_000_003) -> list[np.ndarray]:
    """Photo-like 2-D textures without any data: coloured multi-octave noise, cells and bricks."""
    def upsample(a: np.ndarray) -> np.ndarray:
        return np.stack([np.asarray(Image.fromarray(a[..., c].astype(np.float32)).resize(
            (size, size), Image.BILINEAR)) for c in range(a.shape[-1])], -1)

    out = []
    for k in range(count):
        rng = np.random.default_rng(seed + k)
        img = np.zeros((size, size, 3))
        for octave in range(6):  # 1/f noise per channel
            n = 2 ** (octave + 2)
            layer = upsample(rng.standard_normal((n, n, 3)))
            img += layer * 0.5**octave
        img = (img - img.min((0, 1))) / np.ptp(img, (0, 1))
        if k % 3 == 1:  # cells: nearest random site, each with its own colour
            sites = rng.uniform(0, size, (40, 2))
            yy, xx = np.mgrid[0:size, 0:size]
            idx = np.argmin((yy[..., None] - sites[:, 0]) ** 2 + (xx[..., None] - sites[:, 1]) ** 2, axis=-1)
            img = 0.6 * rng.uniform(0, 1, (40, 3))[idx] + 0.4 * img
        elif k % 3 == 2:  # bricks with mortar lines
            yy, xx = np.mgrid[0:size, 0:size]
            row = yy // 24
            mortar = ((yy % 24) < 3) | (((xx + 24 * (row % 2)) % 48) < 3)
            img = np.where(mortar[..., None], 0.8, img * rng.uniform(0.4, 1.0, 3))
        out.append(np.round(np.clip(img, 0, 1) * 255).astype(np.uint8))
    return out


@lru_cache(maxsize=2)
def texture_set(library: str | None = None) -> tuple[str, Sequence[list[np.ndarray]]]:
    """(source name, mip pyramids): the texture library at ``library`` when given, else the scikit-image
    photographs when available, else procedural images.

    Loaded once per process on first use (never at import); a library's textures are decoded when a scene
    first shows them (:class:`~mvsformerpp.synth.texture_library.TextureLibrary`).
    """
    if library is not None:
        lib = TextureLibrary(library)
        return lib.describe(), lib
    folder = skimage_data_dir()
    images = []
    if folder is not None:
        for name in SKIMAGE_PHOTOS:
            path = folder / name
            if path.is_file():
                with Image.open(path) as im:
                    images.append(np.asarray(im.convert("RGB"), dtype=np.uint8))
    source = "scikit-image sample photographs" if len(images) >= 5 else "procedural images"
    if source == "procedural images":
        images = procedural_images()
    return source, tuple(pyramid(im) for im in images)


@lru_cache(maxsize=1)
def heldout_texture_set() -> tuple[list[np.ndarray], ...]:
    """Procedural images from seeds the training set never uses (the held-out style's textures)."""
    return tuple(pyramid(im) for im in procedural_images(seed=7_000_001))


def texture_source(library: str | None = None) -> str:
    """Which texture set the generator uses here: a texture library, scikit-image's photographs or procedural
    images."""
    return texture_set(library)[0]


def sample_texture(levels: list[np.ndarray], uv: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] ([N,3]) of a mip pyramid at texel coordinates ``uv`` [N,2] of the finest level.

    ``footprint`` [N]: texels of the finest level covered by one image pixel; the level whose texel is
    closest to it is used (mirrored repetition, bilinear within the level).
    """
    level = np.clip(np.round(np.log2(np.maximum(footprint, 1e-6))), 0, len(levels) - 1).astype(np.int64)
    out = np.zeros((len(uv), 3))
    for lv in np.unique(level):
        m = level == lv
        tex = levels[lv]
        h, w = tex.shape[:2]
        q = uv[m] / 2.0**lv - 0.5
        x0f, y0f = np.floor(q[:, 0]), np.floor(q[:, 1])
        fx, fy = (q[:, 0] - x0f)[:, None], (q[:, 1] - y0f)[:, None]

        def mirror(i, n):
            i = np.mod(i.astype(np.int64), 2 * n)
            return np.where(i < n, i, 2 * n - 1 - i)

        x0, x1 = mirror(x0f, w), mirror(x0f + 1, w)
        y0, y1 = mirror(y0f, h), mirror(y0f + 1, h)
        top = tex[y0, x0] * (1 - fx) + tex[y0, x1] * fx
        bottom = tex[y1, x0] * (1 - fx) + tex[y1, x1] * fx
        out[m] = (top * (1 - fy) + bottom * fy) / 255.0
    return out
