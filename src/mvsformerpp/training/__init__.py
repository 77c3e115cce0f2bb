"""Training: config and recipes, the trainer, schedules, DDP, checkpoints and run logs.

The configuration is imported eagerly (``train``'s flags are made from it without torch:
tests/cli/test_startup.py); the trainer, which needs torch, on first use of its names.
"""

from __future__ import annotations

import importlib

from mvsformerpp.training.config import RECIPES, TrainConfig, load_config

__all__ = ["RECIPES", "TrainConfig", "TrainingError", "load_config", "train"]

_LAZY = {"TrainingError": "trainer", "train": "trainer"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"mvsformerpp.training.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
