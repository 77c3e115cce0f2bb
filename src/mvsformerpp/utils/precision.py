"""Autocast precisions: the names accepted, their dtypes, and the context that runs under one."""

from __future__ import annotations

import contextlib
import functools
from pathlib import Path

import torch

PRECISIONS: dict[str, torch.dtype | None] = {"auto": None, "fp32": None, "bf16": torch.bfloat16,
                                              "fp16": torch.float16}
"""Precision name -> autocast dtype (None: no autocast). ``auto`` is fp32, with the cost-volume
transformer's softmax attention in bf16 where that was measured to be faster at no cost
(:func:`attention_in_bf16`)."""


def check_precision(precision: str) -> str:
    """``precision`` if it is one of :data:`PRECISIONS`; else ValueError naming the choices."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    return precision


def autocast(device: str | torch.device, precision: str) -> contextlib.AbstractContextManager:
    """``torch.autocast`` on ``device``'s type with ``precision``'s dtype, or a null context for fp32."""
    dtype = PRECISIONS[check_precision(precision)]
    if dtype is None:
        return contextlib.nullcontext()
    return torch.autocast(device_type=torch.device(device).type, dtype=dtype)


def autocast_enabled(device_type: str) -> bool:
    """Whether an autocast is active for ``device_type`` ("cpu", "cuda") where this is called."""
    try:
        return torch.is_autocast_enabled(device_type)
    except TypeError:  # torch < 2.4 takes no device type
        return torch.is_autocast_cpu_enabled() if device_type == "cpu" else torch.is_autocast_enabled()


@functools.lru_cache(maxsize=1)
def cpu_bf16_flags() -> frozenset[str]:
    """This CPU's native bf16 features among ``avx512_bf16`` and ``amx_bf16`` (from /proc/cpuinfo; empty
    where that file cannot be read, as on macOS and Windows)."""
    try:
        words = set(Path("/proc/cpuinfo").read_text().split())
    except OSError:
        return frozenset()
    return frozenset(words & {"avx512_bf16", "amx_bf16"})


def cpu_attention_in_bf16() -> bool:
    """Whether PyTorch's CPU attention gains from bf16 here: on CPUs with AMX tiles (about 1.3x faster than
    fp32 on a Xeon with ``amx_bf16``); with AVX-512 alone it is slower in bf16 than in fp32."""
    return "amx_bf16" in cpu_bf16_flags()


def attention_in_bf16(device: str | torch.device, precision: str, eligible: bool) -> bool:
    """Whether a run at ``precision`` on ``device`` takes the stage-1 cost-volume transformer's softmax
    attention in bf16 inside an otherwise fp32 network: ``auto`` with a network whose preset is ``eligible``
    (:attr:`~mvsformerpp.models.presets.NetworkPreset.attention_bf16`: the ``lite`` network) on a CPU with
    AMX, where PyTorch's attention runs about 1.4x faster in bf16 and the depth maps were measured to move
    by at most about 0.1 % of the depth range (README, Benchmarks); plain fp32 on other devices and CPUs,
    and for the ``paper`` network, whose error in bf16 has no trained weights to be measured with."""
    return (check_precision(precision) == "auto" and eligible and torch.device(device).type == "cpu"
            and cpu_attention_in_bf16())


def describe_precision(device: str | torch.device, precision: str, eligible: bool) -> str:
    """``precision`` as it runs for a network whose preset is ``eligible`` for bf16 attention (False for a
    network of the caller's): ``auto`` names what it resolves to."""
    return precision_name(precision, attention_in_bf16(device, precision, eligible))


def precision_name(precision: str, attention_bf16: bool) -> str:
    """``precision`` with what ``auto`` resolved to, given that decision (:func:`attention_in_bf16`)."""
    if check_precision(precision) != "auto":
        return precision
    return "auto: fp32, stage-1 attention in bf16" if attention_bf16 else "auto: fp32"
