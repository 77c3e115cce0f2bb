"""The MVSFormer++ network: tensors in, tensors out (no files, no CLI).

The presets and configuration are imported eagerly (the command line reads its ``--preset`` choices from
them without torch: tests/cli/test_startup.py); the network and checkpoint code, which need torch, on first
use of their names.
"""

from __future__ import annotations

from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.presets import PRESETS, get_config
from mvsformerpp.utils.lazy import lazy_names

__all__ = ["MVSFormerPP", "ModelConfig", "PRESETS", "build_model", "get_config", "load_checkpoint", "load_model",
           "save_checkpoint"]

_LAZY = {"MVSFormerPP": "mvsformer", "build_model": "mvsformer", "load_checkpoint": "checkpoint",
         "load_model": "checkpoint", "save_checkpoint": "checkpoint"}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
