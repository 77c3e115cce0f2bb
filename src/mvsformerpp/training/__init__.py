"""Training: config and recipes, the trainer, schedules, DDP, checkpoints and run logs.

The configuration is imported eagerly (``train``'s flags are made from it without torch:
tests/cli/test_startup.py); the trainer, which needs torch, on first use of its names.
"""

from __future__ import annotations

from mvsformerpp.training.config import RECIPES, TrainConfig, load_config
from mvsformerpp.utils.lazy import lazy_names

__all__ = ["RECIPES", "TrainConfig", "TrainingError", "load_config", "train"]

_LAZY = {"TrainingError": "trainer", "train": "trainer"}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
