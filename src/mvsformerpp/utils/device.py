"""The ``--device`` option: a torch device this machine can compute on, or one clear error."""

from __future__ import annotations

from mvsformerpp.errors import InputError


def parse_device(name: str, flag: str = "--device"):
    """``torch.device(name)`` for ``cpu``, ``cuda``/``cuda:N`` (present) or ``mps`` (available); else InputError."""
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, ValueError, TypeError) as e:
        raise InputError(f"{flag} {name!r} is not a torch device (use cpu, cuda or cuda:N)") from e
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise InputError(f"{flag} {name}: CUDA is not available on this machine; use {flag} cpu")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise InputError(f"{flag} {name}: this machine has {torch.cuda.device_count()} CUDA device(s) "
                             f"(cuda:0 .. cuda:{torch.cuda.device_count() - 1})")
    elif device.type == "mps":
        if not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
            raise InputError(f"{flag} {name}: MPS is not available on this machine; use {flag} cpu")
    elif device.type != "cpu":
        raise InputError(f"{flag} {name}: computing on '{device.type}' devices is not supported; use cpu or cuda")
    return device
