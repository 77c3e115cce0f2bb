"""Training: config and recipes, the trainer, schedules, DDP, checkpoints and run logs."""

from mvsformerpp.training.config import RECIPES, TrainConfig, load_config
from mvsformerpp.training.trainer import TrainingError, train

__all__ = ["RECIPES", "TrainConfig", "TrainingError", "load_config", "train"]
