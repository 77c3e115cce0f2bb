"""Learning-rate schedule and the multi-scale batch sampler."""

import math

import torch

from mvsformerpp.data.samplers import MultiScaleBatchSampler
from mvsformerpp.training.schedule import build_scheduler, warmup_cosine


def test_warmup_then_cosine_to_min_ratio():
    assert warmup_cosine(0, 500, 10000, 0.01) == 0.0
    assert warmup_cosine(250, 500, 10000, 0.01) == 0.5
    assert warmup_cosine(500, 500, 10000, 0.01) == 1.0
    mid = 500 + (10000 - 500) / 2
    assert math.isclose(warmup_cosine(mid, 500, 10000, 0.01), 0.01 + 0.99 * 0.5)
    assert math.isclose(warmup_cosine(10000, 500, 10000, 0.01), 0.01)
    p = torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.AdamW([p], lr=2.0)
    sched = build_scheduler(opt, 2, 10, 0.1)
    lrs = []
    for _ in range(4):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs[:3] == [0.0, 1.0, 2.0] and lrs[3] < 2.0


def test_sampler_epoch_order_resolutions_shards_and_resume():
    res = [(64, 96), (96, 128)]
    full = list(MultiScaleBatchSampler(10, 4, res, seed=3, epoch=1))
    assert len(full) == 2 and [(k.height, k.width) for k in full[1]] == [(96, 128)] * 4
    ids = [k.index for b in full for k in b]
    assert len(set(ids)) == 8 and all(k.epoch == 1 for b in full for k in b)
    assert [k.index for k in full[0]] != [k.index for k in list(MultiScaleBatchSampler(10, 4, res, seed=3))[0]]
    shards = [list(MultiScaleBatchSampler(10, 4, res, seed=3, epoch=1, rank=r, world_size=2)) for r in range(2)]
    assert [k.index for k in shards[0][0] + shards[1][0]] == [k.index for k in full[0]]
    resumed = list(MultiScaleBatchSampler(10, 4, res, seed=3, epoch=1, start=1))
    assert resumed == full[1:] and resumed[0][0].height == 96  # the resolution follows the batch number


def test_sampler_blocks_keep_consecutive_samples_together_and_cover_the_epoch():
    """``block``: the order shuffles runs of consecutive samples (a synthetic scene's views), each run whole
    and in index order, every sample once per epoch (a short last block included); resumable as before."""
    res = [(64, 96)]
    blocked = list(MultiScaleBatchSampler(23, 5, res, seed=7, epoch=2, block=5, drop_last=False))
    ids = [k.index for b in blocked for k in b]
    assert sorted(ids) == list(range(23))
    runs = [ids[i:i + 5] for i in range(0, 20, 5)]
    whole = [r for r in runs if r == list(range(r[0], r[0] + 5))]
    assert len(whole) >= 3 and all(r[0] % 5 == 0 for r in whole)  # (the 3-sample block shifts one run)
    assert [b[0] for b in [ids[i:i + 5] for i in range(0, 20, 5)]] != [0, 5, 10, 15]  # shuffled
    assert blocked != list(MultiScaleBatchSampler(23, 5, res, seed=7, epoch=3, block=5, drop_last=False))
    assert list(MultiScaleBatchSampler(23, 5, res, seed=7, epoch=2, block=5, start=2, drop_last=False)) == blocked[2:]
    import pytest

    from mvsformerpp.errors import InputError

    with pytest.raises(InputError, match="block must be at least one sample"):
        MultiScaleBatchSampler(23, 5, res, block=0)
