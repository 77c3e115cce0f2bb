"""``reconstruct``: photos / a COLMAP project / an MVSNet folder / a Middlebury set -> depth maps -> PLY.

The run is a straight line of stages, each in a module of its own and each resumable (the output
layout: :mod:`mvsformerpp.io.output_folder`):

1. :mod:`.scene_input`: the input as a checked Scene (structure from motion for a photo folder,
   undistortion for a distorted COLMAP project, the user's overrides);
2. :mod:`.run_plan`: the working resolution and what each view's depth map depends on;
3. :mod:`.network`: the network and its weights (built only when a view is left to compute);
4. :mod:`.depth_maps`: the scene in the output folder, then the depth map of every view not done yet;
5. :mod:`.fuse`: the depth maps fused into ``OUT/fused.ply``;
6. the summary (``summary.json``) and ``report.html``.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from functools import partial
from pathlib import Path

import torch

from mvsformerpp.errors import InputError
from mvsformerpp.io.output_folder import DEPTH_VIS, SUMMARY, OutputFolder, disk_full_guard, scene_fingerprint
from mvsformerpp.io.scene import Scene
from mvsformerpp.pipelines.backend import describe_backend, resolve_backend, run_model
from mvsformerpp.pipelines.depth_maps import DepthMapsDone, compute_depth_maps, write_layout
from mvsformerpp.pipelines.network import describe_weights
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig, config_flag
from mvsformerpp.pipelines.run_plan import RunPlan, cap_views, plan_line, plan_run, working_long_side
from mvsformerpp.pipelines.scene_input import load_input, prepare_scene, warn_if_range_misses_scene

__all__ = ["ReconstructConfig", "reconstruct"]


def reconstruct(input_path: str | Path, out_dir: str | Path, config: ReconstructConfig | None = None,
                quiet: bool = False, model: torch.nn.Module | None = None) -> dict:
    """Reconstruct INPUT into ``out_dir``; return the summary (also written to ``summary.json``).

    ``config``: the settings (None: the command line's defaults). ``model`` replaces the preset's network
    (already on the device), e.g. for tests or benchmarks.
    Finished views are skipped on a repeated call with the same settings. ``out_dir`` must not be,
    contain or lie inside INPUT, nor hold files of anything but an earlier ``reconstruct``; one run
    at a time holds it (:mod:`mvsformerpp.utils.output_guard`). Under ``torchrun`` the processes share
    the views out (:mod:`mvsformerpp.inference.ranks`), rank 0 holds the folder for them and fuses.
    """
    from mvsformerpp.inference.ranks import ranks_from_env
    from mvsformerpp.utils.output_guard import claim_output_folder

    config = config or ReconstructConfig()
    if not Path(input_path).exists():
        raise InputError("no such file or folder", input_path)
    if config.checkpoint is not None and model is None and not Path(config.checkpoint).is_file():
        raise InputError("checkpoint file not found", config.checkpoint)
    _device(config.device)
    ranks = ranks_from_env(config.device)
    try:
        with claim_output_folder(out_dir, [input_path], "reconstruct"):
            return _run(input_path, out_dir, config, quiet or not ranks.is_main, model, ranks)
    finally:
        ranks.close()


def _run(input_path, out_dir, config: ReconstructConfig, quiet: bool, model, ranks) -> dict:
    """The stages in order; under torchrun every rank runs this, :class:`~mvsformerpp.inference.ranks.Ranks`
    says which rank does what and exchanges the outcomes."""
    t0, started = time.perf_counter(), time.time()
    ranks.agree({"INPUT": str(input_path), "-o": str(out_dir),
                 **{config_flag(k): v for k, v in dataclasses.asdict(config).items()}})
    folder = ranks.in_turn(partial(open_output_folder, out_dir, ranks))
    ranks.check_shared_folder(folder.root)

    # 1. the input
    full = ranks.in_turn(partial(load_input, input_path, folder.root, quiet=quiet, depth_range=config.depth_range,
                                 depth_format=config.depth_format, sfm=config.sfm))
    fingerprint, scene, device = ranks.step(partial(check_input, full, folder, config, ranks))
    config = cap_views(config, len(scene), say=ranks.is_main)
    ranks.agree({"the input scene (cameras and images)": fingerprint})
    if config.depth_range is not None and ranks.is_main:
        warn_if_range_misses_scene(input_path, folder.root, config)
    check_masks(config, scene)
    timings: dict[str, float | int | bool] = {"input_s": time.perf_counter() - t0}
    sfm_report = folder.root / "sfm" / "report.json"
    if sfm_report.is_file():  # written only when SfM runs: older than this run means reused
        timings["sfm_reused"] = sfm_report.stat().st_mtime < started

    # 2. the plan; rank 0's working resolution for all (free memory differs between machines, it may not)
    long_side = ranks.broadcast(working_long_side(scene, config, device))
    backend = resolve_backend(config, device, given_model=model is not None)
    onnx_model = None
    if backend == "onnxruntime":
        if ranks.distributed:
            raise InputError(f"{config_flag('backend')} onnxruntime runs in one process: run it without torchrun")
        onnx_model = run_model(config, folder.root, quiet)
    plan = plan_run(input_path, full, scene, fingerprint, config, device, long_side, given_model=model is not None,
                    backend=backend, onnx_model=onnx_model)

    # 3.-4. the network and the depth maps
    todo = ranks.broadcast(ranks.step(partial(write_layout, folder, plan), only_main=True))
    if not quiet and ranks.is_main:
        print(plan_line(plan, todo), flush=True)
    done = compute_depth_maps(folder, plan, todo, model, ranks, quiet)
    timings.update(depth_s=done.seconds, views_computed=done.computed, views_reused=len(scene) - done.computed)
    per_rank = ranks.gather({"views": done.mine, "depth_s": round(done.seconds, 3),
                             "feature_cache": done.feature_cache})

    # 5.-6. fusion, summary and report (rank 0)
    return ranks.broadcast(ranks.step(partial(finish, folder, plan, done, per_rank, timings, t0, quiet,
                                              ranks.distributed, model is not None), only_main=True))


def open_output_folder(out_dir, ranks) -> OutputFolder:
    """This rank's view of the output folder. Under torchrun, rank 0 opens it first (before any rank
    writes) and removes the temporaries a killed run left, which a single process does when it claims
    the folder (:func:`~mvsformerpp.utils.output_guard.claim_output_folder`)."""
    folder = OutputFolder(out_dir, rank=ranks.rank)
    if ranks.distributed and ranks.is_main:
        from mvsformerpp.utils.output_guard import remove_temporaries

        remove_temporaries(folder.root)
    return folder


def check_input(full: Scene, folder: OutputFolder, config: ReconstructConfig, ranks) -> tuple[str, Scene, torch.device]:
    """The input's fingerprint (refused when the folder holds another scene), the prepared scene and this
    rank's device."""
    fingerprint = scene_fingerprint(full)
    folder.check_scene(fingerprint)
    return fingerprint, prepare_scene(full, config), _device(config.device, ranks)


def check_masks(config: ReconstructConfig, scene: Scene) -> None:
    """Bad masks fail now, not after the depth maps."""
    if config.mask_dir is not None:
        from mvsformerpp.io.masks import load_masks

        load_masks(config.mask_dir, [v.name for v in scene.views], [(v.height, v.width) for v in scene.views])


def finish(folder: OutputFolder, plan: RunPlan, done: DepthMapsDone, per_rank: list[dict], timings: dict,
           t0: float, quiet: bool, distributed: bool, given_model: bool) -> dict:
    """Rank 0 after the depth maps: fusion (unless ``--fusion none`` or already done with these maps and
    settings), then ``summary.json`` and ``report.html``; returns the summary."""
    from mvsformerpp.pipelines.fuse import fuse_reconstruction
    from mvsformerpp.viewer.report import write_report

    folder.fold_rank_progress()
    t2 = time.perf_counter()
    points, reused = fuse_reconstruction(folder, plan, quiet)
    if points is not None:
        timings["fusion_reused"] = reused
    timings["fusion_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0
    config, ply = plan.config, folder.cloud
    summary = {
        "views": len(plan.scene),
        "points": points,
        "working_resolution": plan.resolved,
        "fusion_conf": plan.fusion_conf,
        "preset": config.preset,
        "checkpoint": config.checkpoint,
        "weights": "a network given by the caller" if given_model else describe_weights(config),
        "backend": describe_backend(plan.backend, plan.onnx_model),
        "timings": {k: round(v, 3) if isinstance(v, float) else v for k, v in timings.items()},
        "feature_cache": _sum_stats([r["feature_cache"] for r in per_rank]),
        "schedule": None if done.schedule is None else {k: v for k, v in done.schedule.items() if k != "order"},
        "search_ranges": _widened_ranges(config, folder.progress.get("searched") or {}),
        "ranks": per_rank if distributed else None,
        "outputs": {"ply": str(ply) if points is not None else None,
                    "depth_vis": str(folder.root / DEPTH_VIS), "report": str(folder.report)},
    }
    folder.write_json(SUMMARY, summary)
    with disk_full_guard(folder.report):
        write_report(folder.root)
    return summary


def _widened_ranges(config, searched: dict[str, list[float] | None]) -> dict:
    """``--min-parallax`` and the views whose stage-1 depth range it widened (this run's and those kept
    from an earlier run with the same settings), with the median factor of their inverse-depth spans and
    each one's searched range."""
    ranges = {int(v): r for v, r in searched.items() if r}
    return {"min_parallax": config.stage1_min_parallax, "widened_views": sorted(ranges),
            "median_factor": statistics.median(r[2] for r in ranges.values()) if ranges else None,
            "searched": {f"{v:08d}": r[:2] for v, r in sorted(ranges.items())}}


def _sum_stats(stats: list[dict | None]) -> dict | None:
    """Feature-cache counters of all ranks added up (None when no rank computed a view)."""
    stats = [s for s in stats if s is not None]
    if not stats:
        return None
    return {k: sum(s[k] for s in stats) for k in stats[0]}


def _device(name: str, ranks=None) -> torch.device:
    """The torch device of ``--device``; ``cuda`` under torchrun is each rank's GPU ``LOCAL_RANK``."""
    from mvsformerpp.utils.device import parse_device

    device = parse_device(name)
    if device.type == "cuda" and device.index is None and ranks is not None and ranks.distributed:
        device = torch.device("cuda", ranks.local_rank)
    return device
