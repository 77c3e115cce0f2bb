"""Stage 2 of ``reconstruct``: what the run will do, decided once before any depth map, and the output
folder laid out for it.

A :class:`RunPlan` holds the checked scene, the working resolution of every view, the key of each
view's depth map (its inputs and every setting it depends on: a view whose key is unchanged is not
computed again), the weights, the settings fusion will use and the views left to compute. Every later
stage reads it and none changes it. Rank 0 makes it for all ranks of a torchrun run.
"""

from __future__ import annotations

import dataclasses
import logging
import statistics
from dataclasses import dataclass
from pathlib import Path

import torch

from mvsformerpp.fusion.choice import FusionChoice
from mvsformerpp.inference.fingerprint import view_fingerprints
from mvsformerpp.inference.resolution import (
    ViewResize,
    available_memory_bytes,
    choose_long_side,
    human_size,
    plan_views,
)
from mvsformerpp.inference.runner import view_cameras
from mvsformerpp.inference.search_range import search_range, stage1_shift
from mvsformerpp.io.mvsnet import write_mvsnet_scene
from mvsformerpp.io.output_folder import CONFIG, VIEWS, OutputFolder, disk_full_guard
from mvsformerpp.io.scene import Scene
from mvsformerpp.models.presets import PRESETS, get_config
from mvsformerpp.models.weights import Weights
from mvsformerpp.pipelines.backend import backend_weights
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.pipelines.run import Run
from mvsformerpp.pipelines.scene_input import SceneInput, warn_if_range_misses_scene, working_scene
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
    source: SceneInput
    """What stage 1 made of the input."""
    long_side: int
    """Longer side of the working resolution."""
    plans: list[ViewResize]
    """Working resolution of each view."""
    keys: list[str]
    """Per view: the hash of what its depth map depends on."""
    weights: Weights
    """The weights the network runs, and what runs them (PyTorch or onnxruntime: :mod:`.backend`)."""
    fusion: FusionChoice | None
    """The settings fusion runs with (None: ``--fusion none``)."""
    attention_bf16: bool = False
    """Stage 1's transformer attention in bf16 inside the fp32 network (``--precision auto``, the preset's
    own network only: a network passed by the caller runs as the precision names)."""
    todo: tuple[int, ...] = ()
    """The views whose depth maps are left to compute (the others are done with these keys)."""

    @property
    def scene(self) -> Scene:
        """The views to reconstruct, overrides applied and checked."""
        return self.source.scene

    @property
    def precision(self) -> str:
        """The precision as it runs, as config.json and the view fingerprints record it."""
        return precision_name(self.config.precision, self.attention_bf16)

    @property
    def resolved(self) -> dict:
        """The working resolution as config.json and the summary record it."""
        return resolved_size(self.long_side, self.plans)

    @property
    def fusion_conf(self) -> float | None:
        """Fusion's confidence threshold where it is not the fusion preset's own (given or calibrated), as
        config.json and the summary record it (``--conf`` as given with ``--fusion none``)."""
        return self.config.fusion_conf if self.fusion is None else self.fusion.conf

    @property
    def preview_conf(self) -> float | None:
        """The threshold below which the depth previews grey pixels: what fusion drops (None without fusion)."""
        return None if self.fusion is None else self.fusion.settings.conf_threshold


def make_plan(run: Run, source: SceneInput) -> RunPlan:
    """Stage 2: the plan of the run (what the settings ask of this scene said once), the scene and
    ``config.json`` written into the output folder, and the views left to compute, said before the long
    steps."""
    config = cap_views(run.config, len(source.scene))
    if config.depth_range is not None:
        warn_if_range_misses_scene(run.input_path, run.folder.root, config)
    long_side = working_long_side(source.scene, config, run.device)
    plan = plan_run(run.input_path, source, config, run.device, long_side, backend_weights(run, config))
    plan = dataclasses.replace(plan, todo=tuple(write_layout(run.folder, plan)))
    if not run.quiet:
        print(plan_line(plan), flush=True)
    return plan


def resolved_size(long_side: int, plans: list[ViewResize]) -> dict:
    """The working resolution as config.json, the summary and each view's fingerprint record it."""
    return {"long_side": long_side, "canvas": [plans[0].canvas_width, plans[0].canvas_height]}


def cap_views(config: ReconstructConfig, num_images: int) -> ReconstructConfig:
    """``config`` with at most ``num_images`` views per depth map (more would only repeat source views:
    slower, not better); warns when ``--views`` asked for more."""
    if config.num_views <= num_images:
        return config
    if config.num_views != ReconstructConfig.num_views:  # said when asked for, not by default
        log.warning("the scene has %d images: %d views per depth map (--views %d asks for more than there are)",
                    num_images, num_images, config.num_views)
    return dataclasses.replace(config, num_views=num_images)


def plan_run(input_path: str | Path, source: SceneInput, config: ReconstructConfig, device: torch.device,
             long_side: int, weights: Weights) -> RunPlan:
    """The plan for ``source`` at the working resolution ``long_side`` (:func:`working_long_side`) with
    ``weights`` (:data:`~mvsformerpp.models.weights.GIVEN`: the caller's network; their identity, with the
    exported model's when onnxruntime runs them, enters every view's key)."""
    scene = source.scene
    plans = plan_views([(v.width, v.height) for v in scene.views], long_side)
    resolved = resolved_size(long_side, plans)
    given = weights.source == "given"
    attention_bf16 = (not given and weights.backend == "torch"
                      and attention_in_bf16(device, config.precision, PRESETS[config.preset].attention_bf16))
    settings = {**config.result_settings(), **resolved, "precision": precision_name(config.precision, attention_bf16)}
    if not given:  # the preset's network as built for this run (a given network is the caller's)
        settings["network"] = config.network_settings()
    keys = view_fingerprints(scene, config.num_views, settings, weights.identity)
    return RunPlan(config=config, input_path=Path(input_path), source=source, long_side=long_side, plans=plans,
                   keys=keys, weights=weights, fusion=config.fusion_choice(weights.calibrated_conf),
                   attention_bf16=attention_bf16)


def write_layout(folder: OutputFolder, plan: RunPlan) -> list[int]:
    """Cameras, pairs, images, ``views.json`` and ``config.json`` of the run; returns the views still to do
    (previews of the finished ones are redrawn for the current fusion threshold)."""
    config, scene = plan.config, plan.scene
    working = config.output_resolution == "working"
    with disk_full_guard(folder.root):
        write_mvsnet_scene(working_scene(scene, plan.plans) if working else scene, folder.root, copy_images=False,
                           num_depth=config.num_depth)
        for i, v in enumerate(scene.views):
            if working:
                folder.write_working_image(i, v.image_path, plan.plans[i])
            else:
                folder.link_image(i, v.image_path)
    folder.write_json(VIEWS, {f"{i:08d}": v.name for i, v in enumerate(scene.views)})
    folder.write_json(CONFIG, {"config": dataclasses.asdict(config),
                               "resolved": {**plan.resolved, "fusion_conf": plan.fusion_conf,
                                            "weights": plan.weights.name, "precision": plan.precision,
                                            "backend": plan.weights.backend,
                                            "onnx_model": None if (e := plan.weights.exported) is None
                                            else {"folder": e.folder, "id": e.model_id}},
                               "scene_fingerprint": plan.source.fingerprint, "input": str(plan.input_path.resolve()),
                               "source_format": plan.source.full.source_format,
                               "num_views_in_input": len(plan.source.full)})
    todo = [i for i in range(len(scene)) if not folder.view_done(i, plan.keys[i])]
    done = set(todo)
    folder.redraw_previews([i for i in range(len(scene)) if i not in done], plan.preview_conf)
    return todo


def working_long_side(scene: Scene, config: ReconstructConfig, device: torch.device) -> int:
    """The longer side of the working resolution: the largest that fits the memory budget and ``max_size``."""
    budget = config.memory_gb * 2**30 if config.memory_gb else 0.5 * available_memory_bytes(device)
    return choose_long_side([(v.width, v.height) for v in scene.views], config.num_views, config.max_size, budget)


def plan_line(plan: RunPlan) -> str:
    """What the run is about to do, said before the long steps: views, working size, what is left to compute
    and the disk the depth maps will take."""
    scene, plans, config, todo = plan.scene, plan.plans, plan.config, plan.todo
    working = config.output_resolution == "working"
    pixels = sum((p.resized_width * p.resized_height) if working else (v.width * v.height)
                 for v, p in zip(scene.views, plans))
    size = f"{plans[0].resized_width}x{plans[0].resized_height}"
    left = (f"all {len(todo)} to compute" if len(todo) == len(scene)
            else f"{len(todo)} to compute, {len(scene) - len(todo)} done before")
    disk = pixels * BYTES_PER_OUTPUT_PIXEL
    return (f"plan: {len(scene)} views at {size} (working resolution), {config.num_views} views per depth map; "
            f"{left}; the depth maps take about {human_size(disk)} on disk"
            + ("" if config.fusion == "none" else ", plus the fused cloud"))


def stage1_parallax(scene: Scene, config: ReconstructConfig, device: torch.device) -> dict | None:
    """How far stage 1's neighbouring depth planes move the source images (stage-1 pixels per plane, summed
    over a view's sources) at the working resolution ``reconstruct`` would choose here with ``config``:
    min / median / max over the views that have a depth range and neighbours, and those whose range
    ``--min-parallax`` widens (``info``). None when no view has both."""

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
