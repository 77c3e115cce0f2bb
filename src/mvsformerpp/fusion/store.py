"""Fusion views loaded on demand under a memory budget, for scenes larger than memory.

Fusion of reference view r needs r and its source views only; a :class:`ViewStore` hands
:func:`~mvsformerpp.fusion.core.iter_fused_points` the views as a sequence whose items are read from
disk when first asked for and kept in a least-recently-used cache bounded in bytes
(:class:`~mvsformerpp.utils.lru.BytesLRU`). Neighbouring views share sources, so walking the
references keeps hitting the cache; its size, not the number of views, bounds the memory.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from mvsformerpp.fusion.core import FusionView
from mvsformerpp.fusion.views import make_view
from mvsformerpp.io.scene import Scene
from mvsformerpp.utils.lru import BytesLRU

# Bytes per depth-map pixel of one loaded view: float32 depth and confidence, uint8 RGB.
VIEW_BYTES_PER_PIXEL = 11
# Working memory of fusion per reference pixel and source view in a chunk (config.chunk_pixels).
CHUNK_BYTES_PER_PIXEL = 100


class ViewStore(Sequence):
    """``store[i]`` is view i's :class:`FusionView`, built by ``load(i)`` on a miss and cached (LRU)."""

    def __init__(self, load: Callable[[int], FusionView], count: int, max_bytes: int):
        self._count = int(count)
        self.cache = BytesLRU(load, max_bytes)

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, i: int) -> FusionView:
        if not 0 <= i < self._count:
            raise IndexError(i)
        return self.cache.get(i)

    def stats(self) -> dict[str, int]:
        """Loads (misses), hits and evictions so far."""
        return self.cache.stats()


def scene_view_store(scene: Scene, read: Callable[[int], tuple[np.ndarray, np.ndarray | None, np.ndarray]],
                     max_bytes: int, device: str | torch.device = "cpu") -> ViewStore:
    """A :class:`ViewStore` over ``scene``: ``read(i)`` returns view i's (depth, confidence or None, image)."""
    def load(i: int) -> FusionView:
        depth, conf, image = read(i)
        return make_view(scene.views[i], depth, conf, image, device)

    return ViewStore(load, len(scene), max_bytes)


def working_set_bytes(pixels_per_view: int, num_src_views: int) -> int:
    """Bytes of the views one reference needs at once: itself and its sources."""
    return VIEW_BYTES_PER_PIXEL * pixels_per_view * (1 + num_src_views)
