"""Synthetic multi-view scenes with exact ground truth (tests, benchmarks, training data)."""

from mvsformerpp.synth.render import render_view
from mvsformerpp.synth.scenes import random_scene
from mvsformerpp.synth.writer import generate_dataset, generate_scene

__all__ = ["generate_dataset", "generate_scene", "random_scene", "render_view"]
