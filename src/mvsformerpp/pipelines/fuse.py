"""``fuse``: depth maps of a scene folder -> one coloured point cloud (binary PLY).

Reads the layout that ``reconstruct`` writes and that MVSNet-family test scripts write
(:class:`~mvsformerpp.io.depth_folder.DepthFolder`).

Fusion streams: each view's maps are read when a reference view first needs them and kept in a
cache bounded by the memory budget (:mod:`mvsformerpp.fusion.store`), and points go to the PLY as
they are produced, so memory does not grow with the number of views. The points are the ones the
in-memory :func:`mvsformerpp.fusion.fuse_depth_maps` gives, in the same order.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from mvsformerpp.errors import InputError
from mvsformerpp.fusion import FusionConfig, iter_fused_points
from mvsformerpp.fusion.choice import Calibration, choose_fusion
from mvsformerpp.fusion.normals import ReferenceAttributes
from mvsformerpp.fusion.store import CHUNK_BYTES_PER_PIXEL, scene_view_store, working_set_bytes
from mvsformerpp.inference.resolution import available_memory_bytes, human_size
from mvsformerpp.io.depth_folder import DepthFolder, fusion_read_size
from mvsformerpp.io.output_folder import (
    CLOUD,
    OutputFolder,
    disk_full_guard,
    read_run_record,
    recorded_fusion_size,
    settings_hash,
)
from mvsformerpp.io.ply import PlyStreamWriter, ply_vertex_count
from mvsformerpp.models.weights import Weights, weights_for
from mvsformerpp.pipelines.depth_maps import DepthMaps
from mvsformerpp.pipelines.empty_cloud import explain_empty_cloud
from mvsformerpp.pipelines.reconstruct_config import fusion_overrides
from mvsformerpp.pipelines.run import Run
from mvsformerpp.pipelines.run_plan import RunPlan
from mvsformerpp.utils.file_kinds import POINT_CLOUD
from mvsformerpp.utils.output_guard import claim_output_file

log = logging.getLogger(__name__)


def working_memory_bytes(pixels_per_view: int, num_sources: int, config: FusionConfig) -> int:
    """Working memory of one chunk of reference pixels checked against its sources."""
    S = max(1, num_sources)
    return CHUNK_BYTES_PER_PIXEL * S * min(pixels_per_view, max(1, config.chunk_pixels // S))


def minimum_memory_bytes(pixels_per_view: int, num_sources: int, config: FusionConfig) -> int:
    """The smallest budget fusion runs in: one chunk's working memory and one reference with its sources."""
    return working_memory_bytes(pixels_per_view, num_sources, config) + working_set_bytes(pixels_per_view,
                                                                                        max(1, num_sources))


def view_cache_bytes(pixels_per_view: int, num_sources: int, config: FusionConfig, memory_bytes: float) -> int:
    """The part of a memory budget left to cache loaded views once a chunk's working memory is set aside.

    Raises InputError when that cannot hold one reference view and its ``num_sources`` source views.
    (The chunk size stays the configured one: it does not change the points, but it changes how the
    floating-point work is batched, and streaming gives the in-memory fusion's points bit for bit.)
    """
    need = minimum_memory_bytes(pixels_per_view, num_sources, config)
    if memory_bytes < need:
        raise InputError(
            f"--memory-gb {memory_bytes / 2**30:.3g} is too small for fusion: one reference view and its "
            f"{num_sources} source views need about {human_size(need)}; raise --memory-gb to at least "
            f"{need / 2**30:.2g} or lower --num-src-views")
    return int(memory_bytes - working_memory_bytes(pixels_per_view, num_sources, config))


RECORDED = "recorded"
"""``max_size`` of :func:`fuse`: the size a ``reconstruct`` run's config.json asks fusion to read its maps at."""


def fuse(folder: str | Path, out_ply: str | Path | None = None, config: FusionConfig | None = None,
         device: str = "cpu", quiet: bool = False, memory_gb: float | None = None,
         mask_dir: str | Path | None = None, normals: bool = True, explain_empty: bool = True,
         max_size: int | str | None = RECORDED) -> Path:
    """Fuse the depth maps of ``folder`` into ``out_ply`` (default ``folder/fused.ply``); returns its path.

    The defaults are the ``fuse`` command's: ``config`` None is the ``normal`` preset with the threshold
    calibrated for the shipped weights when they made the depth maps (:func:`default_fusion_config`).
    ``memory_gb`` bounds the loaded views and working memory (default: half of the free memory).
    ``mask_dir``: object masks (:mod:`mvsformerpp.io.masks`); depths outside them are dropped before
    fusion. ``normals``: store each point's normal and confidence from its reference view's maps
    (:mod:`mvsformerpp.fusion.normals`). ``explain_empty``: when no point survives, log why and which
    settings would keep points (trial fusions; parameter sweeps turn this off). ``max_size``: fuse maps larger
    than this (longer side, pixels) at this size (:class:`~mvsformerpp.io.depth_folder.DepthFolder`); None or
    0: at their stored size;
    ``"recorded"``: at the working resolution a ``reconstruct`` run of ``folder`` recorded (else stored).

    ``out_ply`` is replaced only when it is new or a point cloud this package wrote, and not while another
    run writes it or its folder (:func:`~mvsformerpp.utils.output_guard.claim_output_file`); a full disk or a
    read-only place is one clear error, and an unfinished cloud never replaces the old one.
    """
    return fuse_streaming(folder, out_ply, config, device, quiet, memory_gb, mask_dir, normals, explain_empty,
                          max_size)["ply"]


def default_fusion_config(folder: str | Path, name: str = "normal", **overrides) -> FusionConfig:
    """The fusion preset ``name`` as the ``fuse`` command applies it to ``folder``: without a
    ``conf_threshold`` override, the threshold calibrated for the shipped weights when they made its depth
    maps (its config.json says so), else the preset's."""
    conf = overrides.pop("conf_threshold", None)
    return choose_fusion(name, recorded_calibration(folder), conf, **overrides).settings


def fuse_streaming(folder: str | Path, out_ply: str | Path | None = None, config: FusionConfig | None = None,
                   device: str = "cpu", quiet: bool = False, memory_gb: float | None = None,
                   mask_dir: str | Path | None = None, normals: bool = True, explain_empty: bool = True,
                   max_size: int | str | None = RECORDED) -> dict:
    """:func:`fuse`, returning ``{"ply", "points", "seconds", "view_cache": {hits, misses, ...}}``."""

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("no such folder", folder)
    out_ply = Path(out_ply) if out_ply is not None else folder / CLOUD
    config = config or default_fusion_config(folder)
    if memory_gb is not None and not (math.isfinite(memory_gb) and memory_gb > 0):
        raise InputError(f"--memory-gb must be a positive number of GB, got {memory_gb}")
    max_size = fusion_read_size(recorded_fusion_size(folder) if max_size == RECORDED else max_size)
    with claim_output_file(out_ply, POINT_CLOUD, [mask_dir] if mask_dir is not None else [], run=folder):
        return _fuse_streaming(folder, out_ply, config, device, quiet, memory_gb, mask_dir, normals, explain_empty,
                               max_size)


def _fuse_streaming(folder: Path, out_ply: Path, config: FusionConfig, device: str, quiet: bool,
                    memory_gb: float | None, mask_dir, normals: bool, explain_empty: bool,
                    max_size: int | None) -> dict:

    depths = DepthFolder(folder, mask_dir, max_size)
    scene = depths.scene
    budget = memory_gb * 2**30 if memory_gb else 0.5 * available_memory_bytes(torch.device(device))
    pixels = max(h * w for h, w in map(depths.depth_shape, range(len(scene))))
    neighbors = [v.neighbors for v in scene.views]
    sources = max(len([j for j in nb if j != i][: config.num_src_views]) for i, nb in enumerate(neighbors))
    cache_bytes = view_cache_bytes(pixels, sources, config, budget)
    store = scene_view_store(scene, depths.read, cache_bytes, device)
    t0 = time.perf_counter()
    with (tqdm(total=len(scene), desc=f"Fusion ({config.method})", unit="view", disable=quiet) as bar,
          PlyStreamWriter(out_ply) as ply, torch.no_grad()):
        finished = [0]  # reference views done: the pieces in between come from view finished[0]

        def progress(r: int) -> None:
            finished[0] = r + 1
            bar.update(1)
        attributes = ReferenceAttributes(store) if normals else None
        for xyz, rgb in iter_fused_points(store, neighbors, config, progress=progress):
            if attributes is None:
                ply.write(xyz, rgb)
            else:
                point_normals, confidence = attributes(finished[0], xyz)
                ply.write(xyz, rgb, normals=point_normals, extra={"confidence": confidence})
    if ply.count == 0 and explain_empty:

        def count_points(cand: FusionConfig) -> int:
            with torch.no_grad():
                trial = scene_view_store(scene, depths.read, cache_bytes, device)
                return sum(len(xyz) for xyz, _ in iter_fused_points(trial, neighbors, cand))

        log.warning(explain_empty_cloud(depths, config, folder, out_ply, count_points))
    seconds = time.perf_counter() - t0
    if not quiet:
        print(f"{ply.count:,} points in {seconds:.1f} s -> {out_ply}")
    return {"ply": out_ply, "points": ply.count, "seconds": seconds, "view_cache": store.stats()}


def recorded_weights(root: str | Path) -> Weights | None:
    """The weights that made the depth maps of ``root``, as the ``reconstruct`` run that wrote it recorded
    them (None: no such record, e.g. another tool's maps)."""
    record = read_run_record(root)
    if record is None:
        return None
    return weights_for(record["config"].get("preset"), record["config"].get("checkpoint"))


def recorded_calibration(root: str | Path) -> Calibration | None:
    """The fusion thresholds calibrated for the weights that made the depth maps of ``root`` (None: unknown)."""
    weights = recorded_weights(root)
    return None if weights is None else weights.calibrated_conf


@dataclass(frozen=True)
class Fused:
    """What stage 5 of ``reconstruct`` makes."""

    maps: list[DepthMaps]
    """What stage 4 made on every process, rank 0's first."""
    points: int | None
    """Points of the fused cloud (None: ``--fusion none``)."""
    reused: bool
    """The cloud of an earlier run with the same depth maps and settings was kept."""
    seconds: float


def fuse_maps(run: Run, maps: list[DepthMaps]) -> Fused:
    """Stage 5 of ``reconstruct`` (rank 0): the processes' records folded into ``progress.json``, then the
    depth maps fused into ``fused.ply`` as the plan says (:func:`fuse_reconstruction`)."""
    run.folder.fold_rank_progress()
    t = time.perf_counter()
    points, reused = fuse_reconstruction(run.folder, maps[0].plan, run.quiet)
    return Fused(maps, points, reused, time.perf_counter() - t)


def fuse_reconstruction(folder: OutputFolder, plan: RunPlan, quiet: bool) -> tuple[int | None, bool]:
    """Fuse the depth maps of ``folder`` as the run's plan says, unless the same maps were already fused with
    the same settings. Returns the number of points (None with ``--fusion none``) and whether fusion was
    reused."""
    config, choice = plan.config, plan.fusion
    if choice is None:
        return None, False
    ply = folder.cloud
    max_size = plan.long_side if config.fusion_resolution == "working" else None
    given = {k: v for k, v in fusion_overrides(config).items() if v is not None}
    state = settings_hash({"depth": plan.keys, "fusion": config.fusion, "conf": plan.fusion_conf, **given,
                           **({"max_size": max_size} if max_size else {}),
                           **({"masks": str(Path(config.mask_dir).resolve())} if config.mask_dir else {})})
    reused = folder.fusion_done(state)
    if not reused:
        with disk_full_guard(ply):
            fuse(folder.root, ply, choice.settings, quiet=quiet,
                 memory_gb=config.memory_gb, mask_dir=config.mask_dir, max_size=max_size)
        folder.mark_fusion(state)
    return ply_vertex_count(ply), reused
