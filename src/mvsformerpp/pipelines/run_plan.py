"""Stage 2 of ``reconstruct``: what the run will do, decided once before any depth map.

A :class:`RunPlan` holds the checked scene, the working resolution of every view, the key of each
view's depth map (its inputs and every setting it depends on: a view whose key is unchanged is not
computed again), the weights and the confidence threshold fusion will use. Every later stage reads it
and none changes it.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import torch

from mvsformerpp.inference.fingerprint import view_fingerprints, weights_identity
from mvsformerpp.inference.resolution import ViewResize, available_memory_bytes, choose_long_side, plan_views
from mvsformerpp.io.onnx_model import OnnxModel
from mvsformerpp.io.scene import Scene
from mvsformerpp.pipelines.network import fusion_conf_for, fusion_preset, network_settings, weights_id, weights_name
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.utils.precision import attention_in_bf16, precision_name

log = logging.getLogger(__name__)

BYTES_PER_OUTPUT_PIXEL = 11
"""Disk per pixel of a view's outputs: depth and confidence PFM (4 + 4 bytes) and two PNG previews (about 3)."""


@dataclass(frozen=True)
class RunPlan:
    """The decisions of one ``reconstruct`` run (see the module docstring)."""

    config: ReconstructConfig
    """The run's settings, ``num_views`` capped at the number of images."""
    input_path: Path
    scene: Scene
    """The views to reconstruct, overrides applied and checked."""
    source_format: str
    input_views: int
    """Views in the input before ``max_images``."""
    fingerprint: str
    """Identity of the input scene (cameras and image sizes), stored in config.json."""
    device: torch.device
    long_side: int
    """Longer side of the working resolution."""
    plans: list[ViewResize]
    """Working resolution of each view."""
    keys: list[str]
    """Per view: the hash of what its depth map depends on."""
    weights: str
    """The weights in a few words (config.json, the report)."""
    fusion_conf: float | None
    """Fusion's confidence threshold (None: the fusion preset's own)."""
    attention_bf16: bool = False
    """Stage 1's transformer attention in bf16 inside the fp32 network (``--precision auto``, the preset's
    own network only: a network passed by the caller runs as the precision names)."""
    backend: str = "torch"
    """What runs the network: ``torch`` or ``onnxruntime`` (``--backend auto`` resolved)."""
    onnx_model: OnnxModel | None = None
    """The model folder the onnxruntime backend runs (None with PyTorch)."""

    @property
    def precision(self) -> str:
        """The precision as it runs, as config.json and the view fingerprints record it."""
        return precision_name(self.config.precision, self.attention_bf16)

    @property
    def resolved(self) -> dict:
        """The working resolution as config.json and the summary record it."""
        return resolved_size(self.long_side, self.plans)

    @property
    def preview_conf(self) -> float | None:
        """The threshold below which the depth previews grey pixels: what fusion drops (None without fusion)."""
        if self.config.fusion == "none":
            return None
        return self.fusion_conf if self.fusion_conf is not None else fusion_preset(self.config.fusion).conf_threshold


def resolved_size(long_side: int, plans: list[ViewResize]) -> dict:
    """The working resolution as config.json, the summary and each view's fingerprint record it."""
    return {"long_side": long_side, "canvas": [plans[0].canvas_width, plans[0].canvas_height]}


def cap_views(config: ReconstructConfig, num_images: int, say: bool) -> ReconstructConfig:
    """``config`` with at most ``num_images`` views per depth map (more would only repeat source views:
    slower, not better); ``say``: warn when ``--views`` asked for more."""
    if config.num_views <= num_images:
        return config
    if say and config.num_views != ReconstructConfig.num_views:  # said when asked for, not by default
        log.warning("the scene has %d images: %d views per depth map (--views %d asks for more than there are)",
                    num_images, num_images, config.num_views)
    return dataclasses.replace(config, num_views=num_images)


def plan_run(input_path: str | Path, full: Scene, scene: Scene, fingerprint: str, config: ReconstructConfig,
             device: torch.device, long_side: int, given_model: bool, backend: str = "torch",
             onnx_model: OnnxModel | None = None) -> RunPlan:
    """The plan for ``scene`` (prepared from the input ``full``) at the working resolution ``long_side``
    (:func:`working_long_side`); ``given_model``: the caller passed its own network (no weights file);
    ``backend`` and ``onnx_model``: what runs the network (:mod:`.backend`). The onnxruntime backend and its
    model's identity enter every view's key."""
    plans = plan_views([(v.width, v.height) for v in scene.views], long_side)
    resolved = resolved_size(long_side, plans)
    weights = None
    if not given_model:  # a checkpoint file's identity, or the shipped weights' digest (new weights redo the views)
        weights = weights_identity(config.checkpoint) if config.checkpoint else weights_id(config)
    attention_bf16 = not given_model and backend == "torch" and attention_in_bf16(device, config.precision,
                                                                                 config.preset)
    settings = {**config.result_settings(), **resolved, "precision": precision_name(config.precision, attention_bf16)}
    if not given_model:  # the preset's network as built for this run (a given network is the caller's)
        settings["network"] = network_settings(config)
    if onnx_model is not None:  # (PyTorch's keys stay as they were before there was another backend)
        settings["backend"] = {"name": backend, "model": onnx_model.model_id}
    keys = view_fingerprints(scene, config.num_views, settings, weights)
    return RunPlan(config=config, input_path=Path(input_path), scene=scene, source_format=full.source_format,
                   input_views=len(full), fingerprint=fingerprint, device=device, long_side=long_side, plans=plans,
                   keys=keys,
                   weights="a network passed to reconstruct()" if given_model else weights_name(config),
                   fusion_conf=config.fusion_conf if given_model else fusion_conf_for(config),
                   attention_bf16=attention_bf16, backend=backend, onnx_model=onnx_model)


def working_long_side(scene: Scene, config: ReconstructConfig, device: torch.device) -> int:
    """The longer side of the working resolution: the largest that fits the memory budget and ``max_size``."""
    budget = config.memory_gb * 2**30 if config.memory_gb else 0.5 * available_memory_bytes(device)
    return choose_long_side([(v.width, v.height) for v in scene.views], config.num_views, config.max_size, budget)


def plan_line(plan: RunPlan, todo: list[int]) -> str:
    """What the run is about to do, said before the long steps: views, working size, what is left to compute
    and the disk the depth maps will take."""
    scene, plans, config = plan.scene, plan.plans, plan.config
    working = config.output_resolution == "working"
    pixels = sum((p.resized_width * p.resized_height) if working else (v.width * v.height)
                 for v, p in zip(scene.views, plans))
    size = f"{plans[0].resized_width}x{plans[0].resized_height}"
    left = (f"all {len(todo)} to compute" if len(todo) == len(scene)
            else f"{len(todo)} to compute, {len(scene) - len(todo)} done before")
    disk = pixels * BYTES_PER_OUTPUT_PIXEL
    return (f"plan: {len(scene)} views at {size} (working resolution), {config.num_views} views per depth map; "
            f"{left}; the depth maps take about {_size(disk)} on disk"
            + ("" if config.fusion == "none" else ", plus the fused cloud"))


def _size(nbytes: float) -> str:
    return f"{nbytes / 2**30:.1f} GB" if nbytes >= 2**30 else f"{max(1, round(nbytes / 2**20))} MB"


def stage1_parallax(scene: Scene, config: ReconstructConfig, device: torch.device) -> dict | None:
    """How far stage 1's neighbouring depth planes move the source images (stage-1 pixels per plane, summed
    over a view's sources) at the working resolution ``reconstruct`` would choose here with ``config``:
    min / median / max over the views that have a depth range and neighbours, and those whose range
    ``--min-parallax`` widens (``info``). None when no view has both."""
    import statistics

    from mvsformerpp.inference.runner import view_cameras
    from mvsformerpp.inference.search_range import search_range, stage1_shift
    from mvsformerpp.models.config import get_config

    usable = [i for i, v in enumerate(scene.views) if v.neighbors and v.depth_min is not None
              and v.depth_max is not None and 0 < v.depth_min < v.depth_max]
    if not usable:
        return None
    num_views = min(config.num_views, len(scene))
    long_side = working_long_side(scene, dataclasses.replace(config, num_views=num_views), device)
    plans = plan_views([(v.width, v.height) for v in scene.views], long_side)
    planes = get_config(config.preset).num_hypotheses[0]
    floor = config.stage1_min_parallax
    shifts, widened = [], []
    for i in usable:
        K, E, sources, width, height = view_cameras(scene, plans, i, num_views)
        near, far = scene.views[i].depth_min, scene.views[i].depth_max
        if floor > 0:
            searched = search_range(K, E, sources, near, far, width, height, floor, planes)
            shifts.append(searched.shift)
            if searched.factor > 1:
                widened.append(i)
        else:  # (search_range keeps every range without measuring it)
            shifts.append(stage1_shift(K, E, sources, near, far, width, height, planes))
    return {"long_side": long_side, "views_per_depth_map": num_views, "views": len(usable),
            "shift": {"min": min(shifts), "median": statistics.median(shifts), "max": max(shifts)},
            "min_parallax": floor, "widened_views": widened}
