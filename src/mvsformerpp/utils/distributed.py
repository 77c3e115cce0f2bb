"""This process's place in a job of several (torchrun): ``RANK``, ``LOCAL_RANK`` and ``WORLD_SIZE``.

:func:`env_rank` is the one reader of these variables; without torchrun a process is rank 0 of 1.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from mvsformerpp.errors import InputError


class RankMixin:
    """``is_main`` and ``distributed`` of a class that has ``rank`` and ``world_size``."""

    rank: int
    world_size: int

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


@dataclass(frozen=True)
class ProcessRank(RankMixin):
    """Rank of this process in the job, its rank on its node, and the number of processes."""

    rank: int
    world_size: int
    local_rank: int


def env_rank() -> ProcessRank:
    """The ranks torchrun put in the environment (``WORLD_SIZE`` 1, ``RANK`` and ``LOCAL_RANK`` 0 when absent).

    A job of several processes (``WORLD_SIZE`` > 1) must name each one's ``RANK``.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and "RANK" not in os.environ:
        raise InputError(f"WORLD_SIZE is {world} but RANK is not set; start the processes with torchrun")
    return ProcessRank(int(os.environ.get("RANK", "0")), world, int(os.environ.get("LOCAL_RANK", "0")))
