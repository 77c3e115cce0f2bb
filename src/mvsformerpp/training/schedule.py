"""Learning-rate schedule of the reference: linear warm-up, then cosine to ``min_ratio``.

``f(t) = t / warmup`` for ``t < warmup``, then ``min_ratio + (1 - min_ratio) (1 + cos(pi (t - warmup) /
(total - warmup))) / 2``; the learning rate of step ``t`` (0-based, before its update) is ``lr f(t)``.
"""

from __future__ import annotations

import math

import torch


def warmup_cosine(step: int, warmup: int, total: int, min_ratio: float) -> float:
    """The factor f(step) above."""
    if step < warmup:
        return step / warmup
    span = max(total - warmup, 1)
    t = min(step - warmup, span) / span
    return min_ratio + (1.0 - min_ratio) * 0.5 * (1.0 + math.cos(math.pi * t))


def build_scheduler(optimizer: torch.optim.Optimizer, warmup: int, total: int,
                    min_ratio: float) -> torch.optim.lr_scheduler.LambdaLR:
    """A LambdaLR stepping once per optimiser step (its state is the step count)."""
    return torch.optim.lr_scheduler.LambdaLR(optimizer, _Factor(warmup, total, min_ratio))


class _Factor:
    """Picklable f(step) for LambdaLR."""

    def __init__(self, warmup: int, total: int, min_ratio: float):
        self.warmup, self.total, self.min_ratio = int(warmup), int(total), float(min_ratio)

    def __call__(self, step: int) -> float:
        return warmup_cosine(step, self.warmup, self.total, self.min_ratio)
