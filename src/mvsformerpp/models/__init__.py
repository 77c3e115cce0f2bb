"""The MVSFormer++ network: tensors in, tensors out (no files, no CLI)."""

from mvsformerpp.models.checkpoint import load_checkpoint, load_model, save_checkpoint
from mvsformerpp.models.config import PRESETS, ModelConfig, get_config
from mvsformerpp.models.mvsformer import MVSFormerPP, build_model

__all__ = ["MVSFormerPP", "ModelConfig", "PRESETS", "build_model", "get_config", "load_checkpoint", "load_model",
           "save_checkpoint"]
