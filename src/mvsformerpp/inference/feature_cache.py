"""A memory-bounded LRU cache of per-image network features.

The per-image part of MVSFormer++ (DINOv2 tokens and FPN-encoder maps) does
not depend on which view is the reference, so each image is encoded once and its features are
reused by every reference view whose source set contains it. The cache holds at most
``max_bytes`` of tensors; the least recently used image is evicted first.

Features are whatever ``model.encode_images`` returns for one image (batch 1): a tensor, or a
dataclass / dict / list / tuple of tensors. :func:`tree_cat` concatenates such structures along the
batch axis so that the cached single-image features of a view set can be handed to ``forward``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import torch

from mvsformerpp.utils.lru import BytesLRU, tree_nbytes

__all__ = ["FeatureCache", "tree_cat", "tree_nbytes"]


def tree_cat(items: list[Any]) -> Any:
    """Concatenate structurally identical feature structures along dim 0 (the image axis).

    Non-tensor leaves (ints, strings, None) must agree and are kept as they are.
    """
    first = items[0]
    if isinstance(first, torch.Tensor):
        return torch.cat(items, dim=0)
    if dataclasses.is_dataclass(first) and not isinstance(first, type):
        return dataclasses.replace(
            first, **{f.name: tree_cat([getattr(x, f.name) for x in items]) for f in dataclasses.fields(first)
                      if f.init}
        )
    if isinstance(first, dict):
        return type(first)((k, tree_cat([x[k] for x in items])) for k in first)
    if isinstance(first, (list, tuple)):
        parts = [tree_cat([x[i] for x in items]) for i in range(len(first))]
        return type(first)(*parts) if hasattr(first, "_fields") else type(first)(parts)
    if any(x != first for x in items[1:]):
        raise ValueError(f"cannot concatenate differing non-tensor feature fields: {items!r}")
    return first


class FeatureCache(BytesLRU):
    """LRU cache ``image index -> features`` bounded by total tensor bytes (:class:`BytesLRU`).

    ``encode(index)`` computes the features of one image on a miss. An entry larger than the whole
    budget is returned but not kept, so ``max_bytes=0`` turns caching off (recompute every time).
    """

    def __init__(self, encode: Callable[[int], Any], max_bytes: int):
        super().__init__(encode, max_bytes)

    def get_many(self, indices: list[int]) -> Any:
        """Features of several images, concatenated along the image axis in the given order.

        Every image of the set is fetched before any is evicted for it, so a set larger than the
        budget still works (the excess is recomputed next time).
        """
        return tree_cat([self.get(i) for i in indices])
