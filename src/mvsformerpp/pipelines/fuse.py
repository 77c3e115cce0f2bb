"""``fuse``: depth maps of a scene folder -> one coloured point cloud (binary PLY).

Reads the layout that ``reconstruct`` writes and that MVSNet-family test scripts write:
``images/``, ``cams/NNNNNNNN_cam.txt``, ``pair.txt``, ``depth_est/NNNNNNNN.pfm`` and
``confidence/NNNNNNNN.pfm`` (or ``.png`` holding confidence x 255). Depth maps may be smaller than
the images (the cameras are then scaled to them).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.fusion import FusionConfig, fuse_depth_maps
from mvsformerpp.io.images import read_image
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import write_ply

log = logging.getLogger(__name__)


def _read_confidence(folder: Path, stem: str, shape) -> np.ndarray | None:
    pfm, png = folder / "confidence" / f"{stem}.pfm", folder / "confidence" / f"{stem}.png"
    if pfm.is_file():
        conf = read_pfm(pfm)
    elif png.is_file():
        conf = read_image(png)[..., 0].astype(np.float32) / 255.0
    else:
        return None
    if conf.shape != shape:
        raise FormatError(f"confidence map is {conf.shape[1]}x{conf.shape[0]}, its depth map {shape[1]}x{shape[0]}",
                          pfm if pfm.is_file() else png)
    return conf


def load_depth_folder(folder: str | Path):
    """(scene, depths, confidences or None, images) from a scene folder with ``depth_est/``."""
    folder = Path(folder)
    scene = load_mvsnet_scene(folder)
    depths, confs, images = [], [], []
    missing = []
    for view in scene.views:
        path = folder / "depth_est" / f"{view.name}.pfm"
        if not path.is_file():
            missing.append(path.name)
            continue
        depth = read_pfm(path)
        if depth.ndim != 2:
            raise FormatError("depth map must have one channel (Pf)", path)
        h, w = depth.shape
        if abs(w * view.height - h * view.width) > max(w, h, view.width, view.height):  # > 1 px off the aspect
            raise FormatError(f"depth map is {w}x{h}, which is not the shape of its {view.width}x{view.height} photo "
                              "(depth maps may be smaller than the photos, with the same aspect ratio)", path)
        depths.append(depth)
        confs.append(_read_confidence(folder, view.name, depth.shape))
        images.append(read_image(view.image_path))
    if missing:
        raise InputError(
            f"{len(missing)} of {len(scene)} views have no depth map in depth_est/ (e.g. {missing[0]}); "
            "run reconstruct first or remove those views' cams", folder)
    has_conf = [c is not None for c in confs]
    if any(has_conf) and not all(has_conf):
        raise InputError("some views have a confidence map and others not (confidence/)", folder)
    return scene, depths, (confs if all(has_conf) else None), images


def fuse(folder: str | Path, out_ply: str | Path | None = None, config: FusionConfig | None = None,
         device: str = "cpu", quiet: bool = False) -> Path:
    """Fuse the depth maps of ``folder`` into ``out_ply`` (default ``folder/fused.ply``); returns its path."""
    folder = Path(folder)
    out_ply = Path(out_ply) if out_ply is not None else folder / "fused.ply"
    config = config or FusionConfig()
    scene, depths, confs, images = load_depth_folder(folder)
    t0 = time.perf_counter()
    with tqdm(total=len(scene), desc=f"Fusion ({config.method})", unit="view", disable=quiet) as bar:
        xyz, rgb = fuse_depth_maps(scene, depths, confs, images, config, device, progress=lambda r: bar.update(1))
    if len(xyz) == 0:
        from mvsformerpp.pipelines.empty_cloud import explain_empty_cloud

        log.warning(explain_empty_cloud(scene, depths, confs, images, config, folder, out_ply, device))
    write_ply(out_ply, xyz, rgb)
    if not quiet:
        print(f"{len(xyz):,} points in {time.perf_counter() - t0:.1f} s -> {out_ply}")
    return out_ply
