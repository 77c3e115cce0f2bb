"""Mip pyramids of texture images: what the generator's photo surfaces sample
(:func:`~mvsformerpp.synth.photos.sample_texture`), made of scikit-image's photographs, procedural images or a
texture library's crops alike."""

from __future__ import annotations

import numpy as np
from PIL import Image

MAX_SIDE = 384
"""Longest side of a texture's finest level (bigger photos are reduced once, at load)."""
LEVELS = 5


def pyramid(img: np.ndarray) -> list[np.ndarray]:
    """Mip levels of an RGB uint8 image: the finest at most :data:`MAX_SIDE` a side, each next one half."""
    pil = Image.fromarray(img)
    if max(pil.size) > MAX_SIDE:
        s = MAX_SIDE / max(pil.size)
        pil = pil.resize((max(8, round(pil.size[0] * s)), max(8, round(pil.size[1] * s))), Image.BOX)
    levels = [np.asarray(pil, dtype=np.uint8)]
    for _ in range(LEVELS - 1):
        w, h = pil.size
        if min(w, h) < 16:
            break
        pil = pil.resize((w // 2, h // 2), Image.BOX)
        levels.append(np.asarray(pil, dtype=np.uint8))
    return levels
