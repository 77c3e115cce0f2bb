"""Training checkpoints: weights as safetensors, the rest of the training state beside them.

``checkpoints/NAME.safetensors`` holds the network (loadable by ``reconstruct --checkpoint``) and
``checkpoints/NAME.state.pt`` the optimiser, scheduler, gradient scaler, sampler position, random
generator states and counters. Both are written to temporary files and renamed (state first, then
weights), and both carry the step, so a resume can tell a matching pair. A full disk leaves the
previous pair untouched and stops the run with a clear message.
"""

from __future__ import annotations

import errno
import io
import random
from contextlib import contextmanager
from pathlib import Path

import torch

from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.models.checkpoint import read_safetensors, save_checkpoint
from mvsformerpp.utils.atomic import atomic_write_bytes


class CheckpointWriteError(MVSFormerError):
    """The checkpoint could not be written (the previous one is intact)."""


@contextmanager
def _write_guard(path: Path):
    try:
        yield
    except OSError as e:
        why = "the disk is full" if e.errno in (errno.ENOSPC, errno.EDQUOT) else f"{e.strerror or e}"
        raise CheckpointWriteError(
            f"{path}: cannot write the checkpoint ({why}); the previous checkpoint is intact. Free some space "
            "and continue with --resume") from e


def rng_state() -> dict:
    state = {"python": random.getstate(), "torch": torch.get_rng_state()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    random.setstate(state["python"])
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_training_checkpoint(folder: Path, name: str, model: torch.nn.Module, state: dict | None) -> Path:
    """Write ``NAME.state.pt`` (if ``state``) then ``NAME.safetensors``; returns the weights path."""
    folder = Path(folder)
    weights = folder / f"{name}.safetensors"
    step = None if state is None else int(state["step"])
    if state is not None:
        buf = io.BytesIO()
        torch.save(state, buf)
        with _write_guard(folder / f"{name}.state.pt"):
            atomic_write_bytes(folder / f"{name}.state.pt", buf.getvalue())
    with _write_guard(weights):
        save_checkpoint(model, weights, extra_metadata=None if step is None else {"step": step})
    return weights


def load_training_checkpoint(folder: Path, name: str, model: torch.nn.Module) -> dict:
    """Load ``NAME.safetensors`` into ``model`` (strict) and return the state from ``NAME.state.pt``."""
    from safetensors import safe_open

    from mvsformerpp.models.checkpoint import load_state_dict_strict

    weights, state_path = Path(folder) / f"{name}.safetensors", Path(folder) / f"{name}.state.pt"
    for p in (weights, state_path):
        if not p.is_file():
            raise InputError("cannot resume: the checkpoint file is missing (run without --resume to start over)", p)
    try:
        state = torch.load(state_path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise InputError(f"cannot resume: unreadable training state ({type(e).__name__}: {e})", state_path) from e
    with safe_open(str(weights), framework="pt") as f:
        step = (f.metadata() or {}).get("step")
    if step is None or int(step) != int(state.get("step", -1)):
        raise InputError(f"cannot resume: the weights (step {step}) and the training state (step "
                         f"{state.get('step')}) do not belong together", weights)
    sd, _ = read_safetensors(weights)
    load_state_dict_strict(model, sd, weights)
    return state
