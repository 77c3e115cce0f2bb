"""Reference-view order for the feature cache: never worse than a brute-force check, better than index order."""

import numpy as np

from mvsformerpp.inference.schedule import cache_friendly_order, simulate_cache


def strip_sets(n: int, sources: int, perm: np.ndarray) -> list[list[int]]:
    """View sets of a camera strip whose views are numbered in the order ``perm`` (view k sits at perm[k])."""
    where = np.argsort(perm)  # position on the strip -> view number
    sets = []
    for k in range(n):
        p = perm[k]
        near = sorted((q for q in range(n) if q != p), key=lambda q: (abs(q - p), q))[:sources]
        sets.append([k] + [int(where[q]) for q in near])
    return sets


def brute_force_lru(order, sets, capacity):
    cache, hits, misses = [], 0, 0
    for r in order:
        for i in sets[r]:
            if i in cache:
                hits += 1
                cache.remove(i)
            else:
                misses += 1
            cache.append(i)
            cache = cache[-capacity:]
    return hits, misses


def test_simulation_matches_a_list_based_lru():
    rng = np.random.default_rng(0)
    sets = [list(rng.integers(0, 12, 4)) for _ in range(12)]
    order = list(rng.permutation(12))
    got = simulate_cache(order, sets, 5)
    assert (got["hits"], got["misses"]) == brute_force_lru(order, sets, 5)


def test_order_visits_every_view_once_and_beats_index_order_on_shuffled_numbering():
    n, capacity = 60, 8
    perm = np.random.default_rng(1).permutation(n)
    sets = strip_sets(n, 4, perm)
    order = cache_friendly_order(list(range(n)), sets, capacity)
    assert sorted(order) == list(range(n))
    scheduled = simulate_cache(order, sets, capacity)
    index = simulate_cache(range(n), sets, capacity)
    # Shuffled numbering: index order re-encodes almost every image of every set; walking the strip
    # encodes each image about once (plus the jumps back where the greedy walk left a gap).
    assert index["misses"] > 3 * n
    assert scheduled["misses"] <= 1.2 * n < index["misses"] / 2
    # Views already in strip order are left in a cache-friendly order too.
    ordered = strip_sets(n, 4, np.arange(n))
    assert simulate_cache(cache_friendly_order(list(range(n)), ordered, capacity), ordered, capacity)["misses"] \
        <= simulate_cache(range(n), ordered, capacity)["misses"]


def test_no_cache_keeps_the_given_order():
    sets = [[0, 1], [1, 0], [2, 1]]
    assert cache_friendly_order([2, 0, 1], sets, 0) == [2, 0, 1]
