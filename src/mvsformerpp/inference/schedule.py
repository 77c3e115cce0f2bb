"""The order in which reference views are computed, chosen for the per-image feature cache.

A reference view needs the features of its view set (itself and its source views). Computing views
in index order re-encodes an image whenever it has left the cache since the last view that used
it; on scenes whose numbering does not follow the camera path (photo collections, COLMAP image
ids) that is most of the time. :func:`cache_friendly_order` walks the pair graph greedily: the next
view is the unvisited one whose view set has the most images in a simulated LRU cache of the real
capacity (ties: the smaller index), so neighbouring views follow each other and the cache keeps
hitting. :func:`simulate_cache` counts the hits and misses of any order, which is what inference
then measures.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence


def simulate_cache(order: Sequence[int], view_sets: Sequence[Sequence[int]], capacity: int) -> dict[str, int]:
    """Hits and misses of an LRU cache of ``capacity`` images over the view sets in ``order``.

    Follows :class:`~mvsformerpp.inference.feature_cache.FeatureCache`: every image of a set is
    fetched in turn, a miss inserts it and evicts the least recently used beyond the capacity.
    """
    cache: OrderedDict[int, None] = OrderedDict()
    hits = misses = 0
    for r in order:
        for i in view_sets[r]:
            if i in cache:
                hits += 1
                cache.move_to_end(i)
                continue
            misses += 1
            if capacity > 0:
                cache[i] = None
                if len(cache) > capacity:
                    cache.popitem(last=False)
    return {"hits": hits, "misses": misses}


def cache_friendly_order(todo: Sequence[int], view_sets: Sequence[Sequence[int]], capacity: int) -> list[int]:
    """An order of the views ``todo`` that keeps an LRU cache of ``capacity`` images hitting (greedy).

    ``view_sets[r]`` lists the images reference view r needs (``[r] + sources``). Starts at the first
    view of ``todo``; each next view has the most images in the simulated cache; when none has any,
    the smallest remaining index. O(views x capacity x set size).
    """
    remaining = set(todo)
    if capacity <= 0 or len(remaining) <= 1:
        return list(todo)
    users: dict[int, list[int]] = {}  # image -> the remaining views that need it
    for r in remaining:
        for i in set(view_sets[r]):
            users.setdefault(i, []).append(r)
    cache: OrderedDict[int, None] = OrderedDict()
    order: list[int] = []
    nxt = todo[0]
    while True:
        order.append(nxt)
        remaining.discard(nxt)
        for i in view_sets[nxt]:
            cache[i] = None
            cache.move_to_end(i)
            if len(cache) > capacity:
                cache.popitem(last=False)
        if not remaining:
            return order
        score: dict[int, int] = {}
        for i in cache:
            for r in users.get(i, ()):
                if r in remaining:
                    score[r] = score.get(r, 0) + 1
        nxt = min(score, key=lambda r: (-score[r], r)) if score else min(remaining)
