"""Stage 4 of ``reconstruct``: the scene in the output folder, then the depth map of every view not done yet.

:func:`write_layout` writes the cameras, pairs and images in the MVSNet layout (fusion reads them from
there) and the run's ``config.json``; :func:`compute_depth_maps` runs the network view by view (in a
cache-friendly order, shared out between the ranks of a torchrun job) and writes each view's maps as
soon as it is done.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import torch

from mvsformerpp.inference.runner import SceneInference
from mvsformerpp.io.output_folder import CONFIG, VIEWS, OutputFolder, disk_full_guard
from mvsformerpp.pipelines.run_plan import RunPlan
from mvsformerpp.pipelines.scene_input import working_scene


@dataclass(frozen=True)
class DepthMapsDone:
    """What :func:`compute_depth_maps` did on this rank."""

    seconds: float
    computed: int
    """Views computed by all ranks in this run."""
    mine: int
    """Views this rank computed."""
    feature_cache: dict | None
    schedule: dict | None
    """The cache-friendly order's statistics (None when nothing was computed)."""


def write_layout(folder: OutputFolder, plan: RunPlan) -> list[int]:
    """Cameras, pairs, images, ``views.json`` and ``config.json`` of the run; returns the views still to do
    (previews of the finished ones are redrawn for the current fusion threshold)."""
    from mvsformerpp.io.mvsnet import write_mvsnet_scene

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
                                                   "weights": plan.weights, "precision": plan.precision,
                                                   "backend": plan.backend,
                                                   "onnx_model": None if plan.onnx_model is None else
                                                   {"folder": str(plan.onnx_model.folder),
                                                    "id": plan.onnx_model.model_id}},
                                      "scene_fingerprint": plan.fingerprint, "input": str(plan.input_path.resolve()),
                                      "source_format": plan.source_format, "num_views_in_input": plan.input_views})
    todo = [i for i in range(len(scene)) if not folder.view_done(i, plan.keys[i])]
    done = set(todo)
    folder.redraw_previews([i for i in range(len(scene)) if i not in done], plan.preview_conf)
    return todo


def start_inference(plan: RunPlan, net: torch.nn.Module, todo: list[int]) -> tuple[SceneInference, dict]:
    """The view-by-view runner of ``net`` over the plan's scene, and its order for the views ``todo``."""
    from mvsformerpp.io.images import read_image

    config, scene = plan.config, plan.scene
    runner = SceneInference(net, scene, plan.plans, lambda i: read_image(scene.views[i].image_path),
                            num_views=config.num_views, num_depth=config.num_depth,
                            temperatures=config.temperatures, device=plan.device, precision=config.precision,
                            cache_bytes=config.cache_mb << 20, output_resolution=config.output_resolution,
                            attention_bf16=plan.attention_bf16, min_parallax=config.stage1_min_parallax)
    return runner, runner.schedule(todo)


def compute_depth_maps(folder: OutputFolder, plan: RunPlan, todo: list[int], model: torch.nn.Module | None,
                       ranks, quiet: bool) -> DepthMapsDone:
    """The depth maps of the views ``todo``, written into ``folder``, by ``model`` or (None) the network of
    the plan's settings, built only when there is a view to compute. Every rank takes its share of the
    order; an error on one rank stops them all."""
    from functools import partial

    from tqdm import tqdm

    from mvsformerpp.inference.ranks import StoppedByOtherRank

    t0 = time.perf_counter()
    if not todo:
        return DepthMapsDone(time.perf_counter() - t0, 0, 0, None, None)
    runner, schedule = ranks.step(partial(_started, plan, model, todo))
    mine = ranks.shard(schedule["order"])
    error = None
    try:
        for i in tqdm(mine, desc="Depth maps", unit="view", disable=quiet):
            stop = ranks.stop_requested(folder.root)
            if stop is not None:
                raise StoppedByOtherRank(stop)
            res = runner.infer(i)
            searched = (*res.search_range, res.range_factor) if res.range_factor > 1 else None
            folder.write_view(i, res.depth, res.confidence, plan.keys[i], plan.preview_conf, searched)
    except Exception as e:  # (exchanged with the other ranks, then raised again)
        error = e
    ranks.outcome(error)
    return DepthMapsDone(time.perf_counter() - t0, len(todo), len(mine), runner.cache.stats(), schedule)


def _started(plan: RunPlan, model: torch.nn.Module | None, todo: list[int]) -> tuple[SceneInference, dict]:
    from mvsformerpp.pipelines.network import build_network

    if model is None and plan.onnx_model is not None:
        from mvsformerpp.inference.onnx_runtime import OnnxNetwork

        model = OnnxNetwork(plan.onnx_model, plan.device)
    return start_inference(plan, model if model is not None else build_network(plan.config), todo)
