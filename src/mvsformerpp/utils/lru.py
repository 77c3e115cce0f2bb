"""A least-recently-used cache bounded by the bytes of the tensors it holds.

Used for the per-image network features of inference and for the depth maps that streaming fusion
loads on demand. Entries are whatever the ``load`` callable returns: a tensor, or a dataclass / dict /
list / tuple of tensors (:func:`tree_nbytes` sizes them).
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import torch


def tree_nbytes(x: Any) -> int:
    """Total bytes of all tensors in a (nested) structure."""
    if isinstance(x, torch.Tensor):
        return x.numel() * x.element_size()
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return sum(tree_nbytes(getattr(x, f.name)) for f in dataclasses.fields(x))
    if isinstance(x, dict):
        return sum(tree_nbytes(v) for v in x.values())
    if isinstance(x, (list, tuple)):
        return sum(tree_nbytes(v) for v in x)
    return 0


class BytesLRU:
    """LRU cache ``key -> value`` bounded by total tensor bytes.

    ``load(key)`` computes a value on a miss. An entry larger than the whole budget is returned but
    not kept, so ``max_bytes=0`` turns caching off (recompute every time).
    """

    def __init__(self, load: Callable[[Any], Any], max_bytes: int):
        self.load = load
        self.max_bytes = int(max_bytes)
        self._entries: OrderedDict[Any, tuple[Any, int]] = OrderedDict()
        self.bytes = 0
        self.hits = 0
        self.misses = 0
        self.evictions = 0

    def __contains__(self, key) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key) -> Any:
        """The value of ``key``, loading it on a miss."""
        if key in self._entries:
            self._entries.move_to_end(key)
            self.hits += 1
            return self._entries[key][0]
        self.misses += 1
        value = self.load(key)
        size = tree_nbytes(value)
        if size <= self.max_bytes:
            while self._entries and self.bytes + size > self.max_bytes:
                _, (_, old) = self._entries.popitem(last=False)
                self.bytes -= old
                self.evictions += 1
            self._entries[key] = (value, size)
            self.bytes += size
        return value

    def stats(self) -> dict[str, int]:
        return {"hits": self.hits, "misses": self.misses, "evictions": self.evictions,
                "entries": len(self._entries), "bytes": self.bytes, "max_bytes": self.max_bytes}
