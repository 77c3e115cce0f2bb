"""Training checkpoints: weights as safetensors, the rest of the training state beside them.

``checkpoints/NAME.safetensors`` holds the network (loadable by ``reconstruct --checkpoint``) and
``checkpoints/NAME.state.pt`` the optimiser, scheduler, gradient scaler, sampler position, random
generator states and counters. Both carry the step. A new pair is written in full beside the current one
before renames put it in place (the current one is kept as ``NAME.prev.*``), so a kill at any instant
leaves a matching pair that a resume takes, and a full disk leaves the current pair and stops the run
with a clear message.
"""

from __future__ import annotations

import errno
import io
import os
import random
import sys
from contextlib import contextmanager
from pathlib import Path

import torch

from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.models.checkpoint import load_state_dict_strict, read_safetensors, save_checkpoint
from mvsformerpp.utils.atomic import atomic_write_bytes
from mvsformerpp.utils.interrupts import deferred_interrupt


class CheckpointWriteError(MVSFormerError):
    """The checkpoint could not be written (the previous one is intact)."""


@contextmanager
def _write_guard(path: Path):
    try:
        yield
    except OSError as e:
        why = "the disk is full" if e.errno in (errno.ENOSPC, errno.EDQUOT) else f"{e.strerror or e}"
        fix = "free some space" if e.errno in (errno.ENOSPC, errno.EDQUOT) else "fix that"
        if any((path.parent / f"last{k}.safetensors").is_file() for k in ("", ".prev", ".next")):
            then = f"the previous checkpoint is intact: {fix} and continue with --resume"
        else:
            then = f"no checkpoint was saved before this one: {fix} and run the same command again (without --resume)"
        raise CheckpointWriteError(f"{path}: cannot write the checkpoint ({why}); {then}") from e


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


def _canonical(x):
    """``x`` rebuilt with every string interned: pickling refers back to a string seen before by identity, so a
    state read back from a checkpoint (fresh string objects) and one built in the run would give other bytes."""
    if isinstance(x, dict):
        return {_canonical(k): _canonical(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_canonical(v) for v in x]
    if isinstance(x, tuple):
        return tuple(_canonical(v) for v in x)
    if isinstance(x, str):
        return sys.intern(x)
    return x


def save_training_checkpoint(folder: Path, name: str, model: torch.nn.Module, state: dict | None) -> Path:
    """Write ``NAME.state.pt`` (if ``state``) and ``NAME.safetensors``; returns the weights path.

    With a state, the new pair is first written completely as ``NAME.next.*``; then the current pair
    becomes ``NAME.prev.*`` and the new one ``NAME.*``, by renames. At every instant a kill leaves a
    weights file and a state file of one step among them, which :func:`load_training_checkpoint`
    finds; a full disk stops before any rename, with the current pair untouched. Ctrl-C during the save
    waits for its end, then stops the run (:func:`~mvsformerpp.utils.interrupts.deferred_interrupt`).
    """
    with deferred_interrupt():
        return _save_training_checkpoint(Path(folder), name, model, state)


def _save_training_checkpoint(folder: Path, name: str, model: torch.nn.Module, state: dict | None) -> Path:
    weights = folder / f"{name}.safetensors"
    if state is None:
        with _write_guard(weights):
            save_checkpoint(model, weights)
        return weights
    buf = io.BytesIO()
    torch.save(_canonical(state), buf)
    state_path = folder / f"{name}.state.pt"
    new_state, new_weights = folder / f"{name}.next.state.pt", folder / f"{name}.next.safetensors"
    with _write_guard(state_path):
        atomic_write_bytes(new_state, buf.getvalue())
        save_checkpoint(model, new_weights, extra_metadata={"step": int(state["step"])})
        for current, kept in ((state_path, folder / f"{name}.prev.state.pt"),
                              (weights, folder / f"{name}.prev.safetensors")):
            if current.is_file():
                os.replace(current, kept)
        os.replace(new_state, state_path)
        os.replace(new_weights, weights)
    return weights


def _weights_step(path: Path) -> int | None:
    from safetensors import safe_open

    try:
        with safe_open(str(path), framework="pt") as f:
            step = (f.metadata() or {}).get("step")
        return None if step is None else int(step)
    except Exception:  # a damaged or foreign file: not a candidate
        return None


def load_training_checkpoint(folder: Path, name: str, model: torch.nn.Module) -> dict:
    """Load the newest matching pair of ``NAME[.prev|.next].safetensors`` and ``NAME[.prev|.next].state.pt``
    (the same step in both) into ``model`` (strict) and return its training state."""

    folder = Path(folder)
    kinds = ("", ".prev", ".next")
    weights_files = [p for k in kinds if (p := folder / f"{name}{k}.safetensors").is_file()]
    state_files = [p for k in kinds if (p := folder / f"{name}{k}.state.pt").is_file()]
    if not weights_files or not state_files:
        missing = folder / (f"{name}.safetensors" if not weights_files else f"{name}.state.pt")
        raise InputError("cannot resume: the checkpoint file is missing (run without --resume to start over)",
                         missing)
    states, errors = {}, []
    for p in state_files:
        try:
            st = torch.load(p, map_location="cpu", weights_only=True)
            states[int(st.get("step", -1))] = st
        except Exception as e:
            errors.append(f"{p.name}: {type(e).__name__}: {e}")
    steps = {p: _weights_step(p) for p in weights_files}
    pairs = sorted(((steps[p], p) for p in weights_files if steps[p] is not None and steps[p] in states),
                   key=lambda x: -x[0])
    if not pairs:
        found = ", ".join(f"{p.name} step {s}" for p, s in steps.items())
        why = f"; unreadable: {'; '.join(errors)}" if errors else ""
        raise InputError(f"cannot resume: no weights and training state of the same step ({found}; states of steps "
                         f"{sorted(states)}{why}); run without --resume in a new folder to start over", folder)
    step, weights = pairs[0]
    sd, _ = read_safetensors(weights)
    load_state_dict_strict(model, sd, weights)
    return states[step]
