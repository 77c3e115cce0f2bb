"""The processes of one reconstruction: one for the plain command, several under ``torchrun``; and the
choreography of ``reconstruct``'s stages among them (:class:`Together`, :meth:`Ranks.perform`).

``torchrun --nproc-per-node N [--nnodes M ...] -m mvsformerpp reconstruct INPUT -o OUT`` starts N x M
copies of the command with ``RANK``/``WORLD_SIZE``/``LOCAL_RANK`` and a rendezvous address in their
environment. :func:`ranks_from_env` then joins them in a process group (gloo for CPU runs; gloo and
NCCL for CUDA runs, each rank on GPU ``LOCAL_RANK``). The group only carries control messages (small
Python objects): the reference views are shared out in contiguous blocks of a cache-friendly order,
every rank writes its own depth maps into the one output folder, and rank 0 fuses once all are done.

The checks that make a multi-process run safe, each with one clear message:

* :meth:`Ranks.agree`: every rank was started with the same arguments (names the first that differs);
* :meth:`Ranks.check_shared_folder`: every rank sees the files the others write in the output folder
  (a folder local to each node would scatter the depth maps);
* :meth:`Ranks.outcome`: a rank that failed is named to the others, which stop and keep what is done.

:class:`Ranks` itself is the single-process case, where all of this is trivial.

Each stage of ``reconstruct`` is a plain function ``stage(run, product) -> product`` that knows nothing
of the other processes; its :class:`Stage` record says how the ranks run it (:class:`Together`), and
:meth:`Ranks.perform` plays that part: who computes, who waits, what is exchanged.
"""

from __future__ import annotations

import secrets
import shutil
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import timedelta
from enum import Enum
from functools import partial
from pathlib import Path
from typing import Any

from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.utils.distributed import RankMixin, env_rank

# How long a rank waits in a collective for the others (the slowest rank may still be computing views).
COLLECTIVE_TIMEOUT = timedelta(hours=6)
# Folder (inside the output folder) for the files ranks use to see each other.
RANKS_DIR = ".ranks"


class RankFailedError(MVSFormerError):
    """Another rank of the run failed."""


class Together(Enum):
    """How the ranks of a run perform a stage (the single process performs it once, all the same)."""

    IN_TURN = "rank 0 first, then the others, each for its own product (what creates shared files)"
    EACH = "every rank at once, each for its own product"
    MAIN = "rank 0 alone; every rank receives its product"
    SHARE = "every rank on its share of the work; every rank receives the products of all, rank 0's first"


@dataclass(frozen=True)
class Stage:
    """A stage of a run: ``run(settings, previous product) -> product``, and how the ranks perform it."""

    run: Callable[[Any, Any], Any]
    together: Together
    agree: Callable[[Any], dict] | None = None
    """What every rank's product must hold the same of (checked after the stage, :meth:`Ranks.agree`)."""


class Ranks(RankMixin):
    """One process: rank 0 of 1. Subclassed by :class:`ProcessGroupRanks` under torchrun."""

    rank = 0
    world_size = 1
    local_rank = 0

    def gather(self, obj: Any) -> list[Any]:
        """``obj`` of every rank, in rank order (on every rank)."""
        return [obj]

    def broadcast(self, obj: Any) -> Any:
        """Rank 0's ``obj`` on every rank."""
        return obj

    def barrier(self) -> None:
        """Wait until every rank got here."""

    def step(self, fn: Callable[[], Any], only_main: bool = False) -> Any:
        """Run ``fn`` (on rank 0 only with ``only_main``), then exchange outcomes: if it failed on any
        rank, every rank raises (the failed one its own error, the others :class:`RankFailedError`)."""
        result, error = None, None
        if self.is_main or not only_main:
            try:
                result = fn()
            except Exception as e:  # (exchanged below, then raised again)
                error = e
        self.outcome(error)
        return result

    def perform(self, stage: Stage, run: Any, product: Any) -> Any:
        """Perform ``stage`` on ``run`` and the previous ``product`` as its :class:`Together` says; a failure
        on any rank stops every rank (:meth:`step`)."""
        work = partial(stage.run, run, product)
        if stage.together is Together.IN_TURN:
            result = self.in_turn(work)
        elif stage.together is Together.EACH:
            result = self.step(work)
        elif stage.together is Together.MAIN:
            result = self.broadcast(self.step(work, only_main=True))
        else:
            result = self.gather(self.step(work))
        if stage.agree is not None:
            self.agree(stage.agree(result))
        return result

    def in_turn(self, fn: Callable[[], Any]) -> Any:
        """Run ``fn`` on rank 0, then on the other ranks (e.g. what may create shared files)."""
        result = self.step(fn, only_main=True)
        other = self.step(fn) if not self.is_main else self.step(lambda: None)
        return result if self.is_main else other

    def agree(self, settings: dict[str, Any]) -> None:
        """Raise InputError on every rank when the ranks were given different ``settings``."""
        differing = []
        for values in zip(*[sorted(s.items()) for s in self.gather(settings)]):
            if any(v != values[0] for v in values[1:]):
                differing.append(values)
        if differing:
            name = differing[0][0][0]
            seen = ", ".join(f"rank {r} has {v[1]!r}" for r, v in enumerate(differing[0]))
            raise InputError(f"the ranks of this torchrun were started with different arguments: {name} differs "
                             f"({seen}); start every rank with the same command")

    def check_shared_folder(self, folder: Path) -> None:
        """Raise InputError on every rank unless every rank sees the files the others write in ``folder``."""

    def shard(self, order: Sequence[int]) -> list[int]:
        """This rank's contiguous block of ``order`` (blocks differ in length by one at most)."""
        n = len(order)
        return list(order[self.rank * n // self.world_size:(self.rank + 1) * n // self.world_size])

    def outcome(self, error: BaseException | None) -> None:
        """Exchange how each rank's work ended; raise RankFailedError if another rank failed."""
        if error is not None:
            raise error

    def stop_requested(self, folder: Path) -> str | None:
        """Another rank failed while this one works (checked between views): its message, else None."""
        return None

    def raise_if_stopped(self, folder: Path) -> None:
        """Raise :class:`StoppedByOtherRank` when another rank failed (:meth:`stop_requested`)."""
        message = self.stop_requested(folder)
        if message is not None:
            raise StoppedByOtherRank(message)

    def close(self) -> None:
        """Leave the process group."""


class ProcessGroupRanks(Ranks):
    """A rank of a torchrun run, in a torch.distributed process group."""

    def __init__(self, rank: int, world_size: int, local_rank: int, dist, owns_group: bool = True):
        self.rank, self.world_size, self.local_rank = rank, world_size, local_rank
        self.dist = dist
        self.owns_group = owns_group
        self.host = socket.gethostname()
        self._folder: Path | None = None

    def gather(self, obj: Any) -> list[Any]:
        out: list[Any] = [None] * self.world_size
        self.dist.all_gather_object(out, obj)
        return out

    def broadcast(self, obj: Any) -> Any:
        box = [obj]
        self.dist.broadcast_object_list(box, src=0)
        return box[0]

    def barrier(self) -> None:
        self.gather(None)  # (an object collective: works on every backend without a device choice)

    def _dir(self, folder: Path) -> Path:
        return Path(folder) / RANKS_DIR

    def check_shared_folder(self, folder: Path) -> None:
        self._folder = Path(folder)
        token = self.broadcast(secrets.token_hex(8))
        d = self._dir(folder)
        if self.is_main:  # a fresh start: no marks of an earlier run
            shutil.rmtree(d, ignore_errors=True)
        self.barrier()
        d.mkdir(parents=True, exist_ok=True)
        probe = d / f"probe-{self.rank}"
        probe.write_text(f"{token} {self.host}\n")
        self.barrier()
        unseen = [r for r in range(self.world_size) if not _holds(d / f"probe-{r}", token)]
        views = self.gather((self.host, unseen))
        self.barrier()
        probe.unlink(missing_ok=True)
        blind = [(r, host, miss) for r, (host, miss) in enumerate(views) if miss]
        if blind:
            r, host, miss = blind[0]
            raise InputError(
                f"the output folder is not shared by all ranks: rank {r} on {host} cannot see the files of "
                f"rank(s) {', '.join(map(str, miss))} "
                f"(on {', '.join(sorted({views[m][0] for m in miss}))}); put -o on a file system that every "
                "node mounts at the same path", folder)

    def stop_requested(self, folder: Path) -> str | None:
        for f in sorted(self._dir(folder).glob("failed-*")):
            try:
                return f.read_text().strip() or f"rank {f.name.split('-')[-1]} failed"
            except OSError:
                return f"rank {f.name.split('-')[-1]} failed"
        return None

    def outcome(self, error: BaseException | None) -> None:
        message = None if error is None else (str(error) or type(error).__name__)
        if error is not None and self._folder is not None:
            # Tell the ranks still computing views to stop (they check between views).
            try:
                self._dir(self._folder).mkdir(parents=True, exist_ok=True)
                (self._dir(self._folder) / f"failed-{self.rank}").write_text(
                    f"rank {self.rank} on {self.host} failed: {message}\n")
            except OSError:
                pass
        failures = [(r, host, m) for r, (host, m) in enumerate(self.gather((self.host, message))) if m is not None]
        if error is not None and not isinstance(error, StoppedByOtherRank):
            raise error
        if failures:
            failed = [f for f in failures if not f[2].startswith(_STOPPED)]
            r, host, m = (failed or failures)[0]
            raise RankFailedError(f"rank {r} (on {host}) failed: {m.removeprefix(_STOPPED)}; the others stopped. "
                                  "What every rank finished is kept: run the same command again to continue")

    def close(self) -> None:
        if self._folder is not None and self.is_main:
            shutil.rmtree(self._dir(self._folder), ignore_errors=True)
        if self.owns_group and self.dist.is_initialized():
            self.dist.destroy_process_group()


_STOPPED = "stopped: "


class StoppedByOtherRank(MVSFormerError):
    """This rank stopped early because another one failed (its message names that rank)."""

    def __init__(self, message: str):
        super().__init__(_STOPPED + message)


def _holds(path: Path, token: str) -> bool:
    try:
        return path.read_text().split()[0] == token
    except (OSError, IndexError):
        return False


def ranks_from_env(device: str) -> Ranks:
    """The ranks of this run: :class:`ProcessGroupRanks` under torchrun (``WORLD_SIZE`` > 1), else one.

    ``device`` is the configured device type: ``cuda`` runs put each rank on GPU ``LOCAL_RANK`` and
    add NCCL to the group; CPU runs use gloo.
    """
    env = env_rank()
    if not env.distributed:
        return Ranks()
    import torch
    import torch.distributed as dist

    rank, world, local_rank = env.rank, env.world_size, env.local_rank
    backend = "gloo"
    if device.startswith("cuda"):
        torch.cuda.set_device(local_rank)
        backend = "cpu:gloo,cuda:nccl"
    owns = not dist.is_initialized()
    if owns:
        dist.init_process_group(backend=backend, timeout=COLLECTIVE_TIMEOUT)
    return ProcessGroupRanks(rank, world, local_rank, dist, owns)
