"""Batch sampling for training: a shuffled epoch order, one resolution per batch, one shard per rank.

The reference cycles consecutive batches through a list of (H, W) resolutions; each
batch holds ``batch_size`` samples in all (the global batch), of which every process takes its own
``batch_size / world_size``. The order of an epoch is a function of (seed, epoch) alone, so the
sampler's whole state is (epoch, batches already taken): a resumed run sees the same batches.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import torch

from mvsformerpp.data.base import SampleKey
from mvsformerpp.errors import InputError


class MultiScaleBatchSampler:
    """Batches of :class:`SampleKey` for one epoch, starting at batch ``start``.

    Args:
        num_samples: dataset length.
        batch_size: global batch (all processes together); must be a multiple of ``world_size``.
        resolutions: (H, W) list; batch k of the epoch gets ``resolutions[k % len]``.
        seed, epoch: the shuffle is ``torch.randperm`` seeded with ``seed + epoch`` (no shuffle if not ``shuffle``).
        rank, world_size: this process takes the ``rank``-th contiguous slice of each global batch.
        start: batches of the epoch to skip (resume).
        drop_last: drop an incomplete last batch (training); otherwise it is kept (validation).
        block: the shuffle moves blocks of this many consecutive samples, each kept together in index
            order (the synthetic recipe's ``synthetic_scene_batches``: a block is one scene's views).
    """

    def __init__(self, num_samples: int, batch_size: int, resolutions: Sequence[tuple[int, int]], seed: int = 0,
                 epoch: int = 0, shuffle: bool = True, rank: int = 0, world_size: int = 1, start: int = 0,
                 drop_last: bool = True, block: int = 1):
        if batch_size % world_size:
            raise InputError(f"the global batch size {batch_size} is not a multiple of the {world_size} processes; "
                             "choose --batch-size accordingly")
        if not resolutions:
            raise InputError("at least one training resolution is needed")
        self.num_samples, self.batch_size = int(num_samples), int(batch_size)
        self.resolutions = [tuple(int(x) for x in r) for r in resolutions]
        self.seed, self.epoch, self.shuffle = int(seed), int(epoch), bool(shuffle)
        self.rank, self.world_size, self.start, self.drop_last = int(rank), int(world_size), int(start), drop_last
        if block < 1:
            raise InputError(f"the shuffle's block must be at least one sample, got {block}")
        self.block = int(block)

    @staticmethod
    def batches_per_epoch(num_samples: int, batch_size: int, drop_last: bool = True) -> int:
        return num_samples // batch_size if drop_last else -(-num_samples // batch_size)

    def __len__(self) -> int:
        return max(0, self.batches_per_epoch(self.num_samples, self.batch_size, self.drop_last) - self.start)

    def order(self) -> list[int]:
        if not self.shuffle:
            return list(range(self.num_samples))
        g = torch.Generator().manual_seed(self.seed + self.epoch)
        if self.block == 1:
            return torch.randperm(self.num_samples, generator=g).tolist()
        blocks = torch.randperm(-(-self.num_samples // self.block), generator=g).tolist()
        return [i for b in blocks for i in range(b * self.block, min((b + 1) * self.block, self.num_samples))]

    def __iter__(self) -> Iterator[list[SampleKey]]:
        order = self.order()
        per_rank = self.batch_size // self.world_size
        n_batches = self.batches_per_epoch(self.num_samples, self.batch_size, self.drop_last)
        for b in range(self.start, n_batches):
            ids = order[b * self.batch_size:(b + 1) * self.batch_size]
            mine = ids[self.rank * per_rank:(self.rank + 1) * per_rank] if self.world_size > 1 else ids
            h, w = self.resolutions[b % len(self.resolutions)]
            yield [SampleKey(i, h, w, self.epoch) for i in mine]
