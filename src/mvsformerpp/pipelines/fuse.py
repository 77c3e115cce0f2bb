"""``fuse``: depth maps of a scene folder -> one coloured point cloud (binary PLY).

Reads the layout that ``reconstruct`` writes and that MVSNet-family test scripts write:
``images/``, ``cams/NNNNNNNN_cam.txt``, ``pair.txt``, ``depth_est/NNNNNNNN.pfm`` and
``confidence/NNNNNNNN.pfm`` (or ``.png`` holding confidence x 255). Depth maps may be smaller than
the images (the cameras are then scaled to them).

Fusion streams: each view's maps are read when a reference view first needs them and kept in a
cache bounded by the memory budget (:mod:`mvsformerpp.fusion.store`), and points go to the PLY as
they are produced, so memory does not grow with the number of views. The points are the ones the
in-memory :func:`mvsformerpp.fusion.fuse_depth_maps` gives, in the same order.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.fusion import FusionConfig, iter_fused_points
from mvsformerpp.fusion.normals import ReferenceAttributes
from mvsformerpp.fusion.store import CHUNK_BYTES_PER_PIXEL, scene_view_store, working_set_bytes
from mvsformerpp.io.images import read_image
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.output_folder import CLOUD
from mvsformerpp.io.pfm import pfm_shape, read_pfm
from mvsformerpp.io.ply import PlyStreamWriter
from mvsformerpp.io.scene import Scene

log = logging.getLogger(__name__)


def _confidence_path(folder: Path, stem: str) -> Path | None:
    for ext in (".pfm", ".png"):
        path = folder / "confidence" / f"{stem}{ext}"
        if path.is_file():
            return path
    return None


def _read_confidence(path: Path, shape) -> np.ndarray:
    conf = read_pfm(path) if path.suffix == ".pfm" else read_image(path)[..., 0].astype(np.float32) / 255.0
    if conf.shape != shape:
        raise FormatError(f"confidence map is {conf.shape[1]}x{conf.shape[0]}, its depth map {shape[1]}x{shape[0]}",
                          path)
    return conf


class DepthFolder:
    """The depth maps of a scene folder, checked up front and read one view at a time.

    With ``mask_dir`` (:mod:`mvsformerpp.io.masks`), depths outside each view's object mask read as 0.
    With ``max_size``, maps whose longer side exceeds it read at that size (:meth:`_resample`): depth maps
    upsampled to large photos fuse at the resolution they were computed at.
    """

    def __init__(self, folder: str | Path, mask_dir: str | Path | None = None, max_size: int | None = None):
        self.root = Path(folder)
        if max_size is not None and max_size < 16:
            raise InputError(f"--max-size must be at least 16 pixels, got {max_size}")
        self.max_size = max_size
        self.scene: Scene = load_mvsnet_scene(self.root)
        missing = [p.name for p in map(self.depth_path, range(len(self.scene))) if not p.is_file()]
        if missing:
            raise InputError(
                f"{len(missing)} of {len(self.scene)} views have no depth map in depth_est/ (e.g. {missing[0]}); "
                "run reconstruct first or remove those views' cams", self.root)
        self.confidence_paths = [_confidence_path(self.root, v.name) for v in self.scene.views]
        has_conf = [p is not None for p in self.confidence_paths]
        if any(has_conf) and not all(has_conf):
            raise InputError("some views have a confidence map and others not (confidence/)", self.root)
        self.has_confidence = all(has_conf)
        self.mask_paths = None
        if mask_dir is not None:
            import json

            from mvsformerpp.io.masks import check_mask_size, mask_paths

            names_file = self.root / "views.json"  # the photos' original names, as reconstruct records them
            original = json.loads(names_file.read_text()) if names_file.is_file() else {}
            names = [original.get(v.name, v.image_path.name) for v in self.scene.views]
            self.mask_paths = mask_paths(mask_dir, names)
            for i, p in enumerate(self.mask_paths):
                check_mask_size(p, *self.depth_shape(i))

    def depth_path(self, i: int) -> Path:
        return self.root / "depth_est" / f"{self.scene.views[i].name}.pfm"

    def stored_shape(self, i: int) -> tuple[int, int]:
        """(height, width) of view i's depth map file."""
        shape = pfm_shape(self.depth_path(i))
        if len(shape) != 2:
            raise FormatError("depth map must have one channel (Pf)", self.depth_path(i))
        (h, w), view = shape, self.scene.views[i]
        if abs(w * view.height - h * view.width) > max(w, h, view.width, view.height):  # > 1 px off the aspect
            raise FormatError(f"depth map is {w}x{h}, which is not the shape of its {view.width}x{view.height} photo "
                              "(depth maps may be smaller than the photos, with the same aspect ratio)",
                              self.depth_path(i))
        return h, w

    def depth_shape(self, i: int) -> tuple[int, int]:
        """(height, width) view i's maps are read at (the stored size, or less under ``max_size``)."""
        h, w = self.stored_shape(i)
        if self.max_size is None or max(h, w) <= self.max_size:
            return h, w
        s = self.max_size / max(h, w)
        return max(1, round(h * s)), max(1, round(w * s))

    def _resample(self, i: int, depth: np.ndarray, conf: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Depth (and confidence) at the centres of the smaller grid: interpolated between the four nearest
        pixels where they lie on one smooth surface (all with depth, within 1 % of each other), else the
        nearest pixel's (no depth is made up across an edge)."""
        h, w = self.depth_shape(i)
        H, W = depth.shape
        if (h, w) == (H, W):
            return depth, conf
        y = np.clip((np.arange(h) + 0.5) * H / h - 0.5, 0, H - 1)
        x = np.clip((np.arange(w) + 0.5) * W / w - 0.5, 0, W - 1)
        y0, x0 = np.minimum(y.astype(np.int64), H - 2), np.minimum(x.astype(np.int64), W - 2)
        fy, fx = (y - y0)[:, None], (x - x0)[None, :]

        def corners(a):
            return a[y0][:, x0], a[y0][:, x0 + 1], a[y0 + 1][:, x0], a[y0 + 1][:, x0 + 1]

        def blend(c):
            return (c[0] * (1 - fx) + c[1] * fx) * (1 - fy) + (c[2] * (1 - fx) + c[3] * fx) * fy

        def nearest(a):
            return a[np.round(y).astype(np.int64)][:, np.round(x).astype(np.int64)]

        d = corners(depth.astype(np.float64))
        lo, hi = np.minimum.reduce(d), np.maximum.reduce(d)
        smooth = (lo > 0) & (hi - lo <= 0.01 * lo)
        out = np.where(smooth, blend(d), nearest(depth)).astype(depth.dtype)
        if conf is not None:
            conf = np.where(smooth, blend(corners(conf.astype(np.float64))), nearest(conf)).astype(conf.dtype)
        return np.ascontiguousarray(out), conf

    def read(self, i: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """View i's (depth, confidence or None, image)."""
        path = self.depth_path(i)
        depth = read_pfm(path)
        if depth.ndim != 2:
            raise FormatError("depth map must have one channel (Pf)", path)
        conf = _read_confidence(self.confidence_paths[i], depth.shape) if self.has_confidence else None
        depth, conf = self._resample(i, depth, conf)
        if self.mask_paths is not None:
            from mvsformerpp.io.masks import fit_mask, read_mask

            mask = fit_mask(read_mask(self.mask_paths[i]), *depth.shape, self.mask_paths[i])
            depth = np.where(mask, depth, 0).astype(depth.dtype)
        return depth, conf, read_image(self.scene.views[i].image_path)


def load_depth_folder(folder: str | Path):
    """(scene, depths, confidences or None, images) of a scene folder with ``depth_est/``, all in memory."""
    f = DepthFolder(folder)
    maps = [f.read(i) for i in range(len(f.scene))]
    return f.scene, [m[0] for m in maps], ([m[1] for m in maps] if f.has_confidence else None), [m[2] for m in maps]


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
    from mvsformerpp.inference.resolution import human_size

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
    than this (longer side, pixels) at this size (:class:`DepthFolder`); None: at their stored size;
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
    from mvsformerpp.fusion import get_config

    if overrides.get("conf_threshold") is None:
        overrides["conf_threshold"] = recorded_calibrated_conf(folder, get_config(name).method)
    return get_config(name, **overrides)


def fuse_streaming(folder: str | Path, out_ply: str | Path | None = None, config: FusionConfig | None = None,
                   device: str = "cpu", quiet: bool = False, memory_gb: float | None = None,
                   mask_dir: str | Path | None = None, normals: bool = True, explain_empty: bool = True,
                   max_size: int | str | None = RECORDED) -> dict:
    """:func:`fuse`, returning ``{"ply", "points", "seconds", "view_cache": {hits, misses, ...}}``."""

    from mvsformerpp.io.output_folder import recorded_fusion_size
    from mvsformerpp.utils.file_kinds import POINT_CLOUD
    from mvsformerpp.utils.output_guard import claim_output_file

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("no such folder", folder)
    out_ply = Path(out_ply) if out_ply is not None else folder / CLOUD
    config = config or default_fusion_config(folder)
    if memory_gb is not None and not (math.isfinite(memory_gb) and memory_gb > 0):
        raise InputError(f"--memory-gb must be a positive number of GB, got {memory_gb}")
    if max_size == RECORDED:
        max_size = recorded_fusion_size(folder)
    with claim_output_file(out_ply, POINT_CLOUD, [mask_dir] if mask_dir is not None else [], run=folder):
        return _fuse_streaming(folder, out_ply, config, device, quiet, memory_gb, mask_dir, normals, explain_empty,
                               max_size)


def _fuse_streaming(folder: Path, out_ply: Path, config: FusionConfig, device: str, quiet: bool,
                    memory_gb: float | None, mask_dir, normals: bool, explain_empty: bool,
                    max_size: int | None) -> dict:
    from mvsformerpp.inference.resolution import available_memory_bytes

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
        from mvsformerpp.pipelines.empty_cloud import explain_empty_cloud

        def count_points(cand: FusionConfig) -> int:
            with torch.no_grad():
                trial = scene_view_store(scene, depths.read, cache_bytes, device)
                return sum(len(xyz) for xyz, _ in iter_fused_points(trial, neighbors, cand))

        log.warning(explain_empty_cloud(depths, config, folder, out_ply, count_points))
    seconds = time.perf_counter() - t0
    if not quiet:
        print(f"{ply.count:,} points in {seconds:.1f} s -> {out_ply}")
    return {"ply": out_ply, "points": ply.count, "seconds": seconds, "view_cache": store.stats()}


def recorded_calibrated_conf(root: str | Path, method: str) -> float | None:
    """The fusion threshold calibrated for the shipped weights when the run of ``root`` used them, else None."""
    from mvsformerpp.io.output_folder import read_run_record
    from mvsformerpp.models import shipped

    record = read_run_record(root)
    if record is None or not shipped.runs_shipped(record["config"].get("preset"), record["config"].get("checkpoint")):
        return None
    return shipped.calibrated_conf(method)


def fuse_reconstruction(folder, plan, quiet: bool) -> tuple[int | None, bool]:
    """Stage 5 of ``reconstruct``: fuse the depth maps of ``folder`` (an
    :class:`~mvsformerpp.io.output_folder.OutputFolder`) as the run's plan (a
    :class:`~mvsformerpp.pipelines.run_plan.RunPlan`) says, unless the same maps were already fused with the
    same settings. Returns the number of points (None with ``--fusion none``) and whether fusion was reused."""
    from mvsformerpp.io.output_folder import disk_full_guard, settings_hash
    from mvsformerpp.io.ply import ply_vertex_count
    from mvsformerpp.pipelines.network import fusion_preset

    config = plan.config
    if config.fusion == "none":
        return None, False
    ply = folder.cloud
    max_size = plan.long_side if config.fusion_resolution == "working" else None
    state = settings_hash({"depth": plan.keys, "fusion": config.fusion, "conf": plan.fusion_conf,
                           **({"max_size": max_size} if max_size else {}),
                           **({"masks": str(Path(config.mask_dir).resolve())} if config.mask_dir else {})})
    reused = folder.fusion_done(state)
    if not reused:
        with disk_full_guard(ply):
            fuse(folder.root, ply, fusion_preset(config.fusion, plan.fusion_conf), quiet=quiet,
                 memory_gb=config.memory_gb, mask_dir=config.mask_dir, max_size=max_size)
        folder.mark_fusion(state)
    return ply_vertex_count(ply), reused
