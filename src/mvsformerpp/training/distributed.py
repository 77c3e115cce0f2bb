"""torchrun + DistributedDataParallel: process group, device, model wrapping, collectives.

Under ``torchrun`` (``WORLD_SIZE`` > 1 in the environment) each process joins the default group:
NCCL on GPUs (one per process, ``cuda:LOCAL_RANK``), gloo on CPUs. BatchNorm layers become
SyncBatchNorm on GPUs (PyTorch implements it for CUDA only; on CPUs every process normalises with its
own batch statistics). Without torchrun everything here is a no-op for one process.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.distributed as dist

from mvsformerpp.errors import InputError
from mvsformerpp.utils.distributed import ProcessRank, env_rank


@dataclass(frozen=True)
class DistInfo(ProcessRank):
    """This process's ranks and the device it trains on."""

    device: torch.device


def init_distributed(device: str) -> DistInfo:
    """Join the torchrun process group if there is one; the device of this process (``auto``: CUDA when
    there is a CUDA device, else the CPU, said on stdout)."""
    ranks = env_rank()
    rank, world, local = ranks.rank, ranks.world_size, ranks.local_rank
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
        if rank == 0:
            found = "a CUDA device is" if device == "cuda" else "no CUDA device"
            print(f"train: device {device} (--device auto: {found} available)", flush=True)
    if device == "cuda":
        if not torch.cuda.is_available():

            raise InputError("--device cuda: no CUDA device is available (use --device cpu)")
        dev = torch.device("cuda", local if world > 1 else torch.cuda.current_device())
        torch.cuda.set_device(dev)
    else:
        dev = torch.device("cpu")
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
    return DistInfo(rank, world, local, dev)


def wrap_model(model: torch.nn.Module, info: DistInfo) -> torch.nn.Module:
    """SyncBatchNorm (CUDA) and DistributedDataParallel when several processes train together."""
    if not info.distributed:
        return model
    from torch.nn.parallel import DistributedDataParallel

    if info.device.type == "cuda":
        model = torch.nn.SyncBatchNorm.convert_sync_batchnorm(model)
    ids = [info.device.index] if info.device.type == "cuda" else None
    return DistributedDataParallel(model, device_ids=ids)


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    return getattr(model, "module", model)


def all_reduce_mean(x: torch.Tensor, info: DistInfo) -> torch.Tensor:
    if info.distributed:
        y = x.to(info.device, copy=True)
        dist.all_reduce(y)
        x = (y / info.world_size).to(x.device)
    return x


def any_rank(flag: bool, info: DistInfo) -> bool:
    """True if ``flag`` is true on any process."""
    if not info.distributed:
        return flag
    t = torch.tensor([1.0 if flag else 0.0], device=info.device)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return bool(t.item() > 0)


def barrier(info: DistInfo) -> None:
    if info.distributed:
        dist.barrier()


def shutdown(info: DistInfo) -> None:
    if info.distributed and dist.is_initialized():
        dist.destroy_process_group()
