from dataclasses import dataclass

import pytest
import torch

from mvsformerpp.inference.feature_cache import FeatureCache, tree_cat, tree_nbytes


@dataclass
class Feats:
    a: torch.Tensor
    b: dict
    name: str = "x"


def make(i):
    return Feats(torch.full((1, 2, 4), float(i)), {"c": [torch.full((1, 3), float(i))]})


def test_tree_cat_and_nbytes():
    out = tree_cat([make(0), make(1), make(2)])
    assert out.a.shape == (3, 2, 4) and out.b["c"][0].shape == (3, 3)
    assert out.a[:, 0, 0].tolist() == [0.0, 1.0, 2.0]
    assert out.name == "x"
    assert tree_nbytes(make(0)) == (8 + 3) * 4
    with pytest.raises(ValueError):
        tree_cat([Feats(torch.zeros(1), {}, "p"), Feats(torch.zeros(1), {}, "q")])


def test_lru_eviction_respects_budget():
    calls = []

    def encode(i):
        calls.append(i)
        return make(i)

    size = tree_nbytes(make(0))
    cache = FeatureCache(encode, max_bytes=2 * size)
    for i in [0, 1, 0, 2, 0, 1]:
        assert cache.get(i).a[0, 0, 0].item() == i
        assert cache.bytes <= cache.max_bytes
    # 0 hit once it was cached; 2 evicts 1 (least recently used); 1 is then re-encoded.
    assert calls == [0, 1, 2, 1]
    assert cache.stats()["hits"] == 2 and cache.evictions == 2


def test_zero_budget_recomputes():
    calls = []
    cache = FeatureCache(lambda i: calls.append(i) or make(i), max_bytes=0)
    cache.get_many([0, 1, 0])
    assert calls == [0, 1, 0] and len(cache) == 0
