"""Stage 3 of ``reconstruct``: the network of the run's preset and settings with the run's weights, and the
runner that takes it over the scene view by view.

Which weights run is decided once (:func:`mvsformerpp.models.weights.weights_for`), and what runs them in
stage 2 (:mod:`.backend`): PyTorch builds the preset's network, onnxruntime opens the exported model
(:class:`~mvsformerpp.inference.onnx_runtime.OnnxNetwork`, the same interface to the runner). Either is
started only when a view is left to compute.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from mvsformerpp.inference.onnx_runtime import OnnxNetwork
from mvsformerpp.inference.runner import SceneInference
from mvsformerpp.io.images import read_image
from mvsformerpp.io.onnx_model import read_model_folder
from mvsformerpp.models.weights import Weights, weights_for
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.pipelines.run import Run
from mvsformerpp.pipelines.run_plan import RunPlan


@dataclass(frozen=True)
class Started:
    """What stage 3 makes: the runner and its order of the views left to compute (None: nothing is left)."""

    plan: RunPlan
    runner: SceneInference | None
    schedule: dict | None
    """The cache-friendly order of the views left (``order``) and its statistics."""
    since: float
    """``time.perf_counter()`` when the stage began (the depth maps' time counts from it)."""


def start_network(run: Run, plan: RunPlan) -> Started:
    """Stage 3: the run's network (the caller's, or the preset's with the run's weights) and its view-by-view
    runner over the plan's scene, with a cache-friendly order of the views left; nothing is built when no
    view is left."""
    since = time.perf_counter()
    if not plan.todo:
        return Started(plan, None, None, since)
    config, scene = plan.config, plan.scene
    net = run.model if run.model is not None else start_weights(plan.weights, config, run.device)
    runner = SceneInference(net, scene, plan.plans, lambda i: read_image(scene.views[i].image_path),
                            num_views=config.num_views, num_depth=config.num_depth,
                            temperatures=config.temperatures, device=run.device, precision=config.precision,
                            cache_bytes=config.cache_mb << 20, output_resolution=config.output_resolution,
                            attention_bf16=plan.attention_bf16, min_parallax=config.stage1_min_parallax)
    return Started(plan, runner, runner.schedule(list(plan.todo)), since)


def start_weights(weights: Weights, config: ReconstructConfig, device: torch.device) -> torch.nn.Module | OnnxNetwork:
    """The network that runs ``weights``: the preset's, built (PyTorch), or their exported model's sessions
    (onnxruntime)."""
    if weights.exported is None:
        return build_network(config, weights)
    return OnnxNetwork(read_model_folder(weights.exported.folder, verify=False), device)


def run_weights(config: ReconstructConfig) -> Weights:
    """The weights a ``reconstruct`` run with ``config`` runs."""
    return weights_for(config.preset, config.checkpoint, config.seed)


def build_network(config: ReconstructConfig, weights: Weights | None = None) -> torch.nn.Module:
    """The preset's network on the configured device with ``weights`` (default: :func:`run_weights`), in
    evaluation mode."""
    weights = weights or run_weights(config)
    return weights.build(config.network_config()).to(torch.device(config.device)).eval()
