"""``fuse``: depth maps of a scene folder -> one coloured point cloud (binary PLY).

Reads the layout that ``reconstruct`` writes and that MVSNet-family test scripts write:
``images/``, ``cams/NNNNNNNN_cam.txt``, ``pair.txt``, ``depth_est/NNNNNNNN.pfm`` and
``confidence/NNNNNNNN.pfm`` (or ``.png`` holding confidence x 255). Depth maps may be smaller than
the images (the cameras are then scaled to them).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.fusion import FusionConfig, fuse_depth_maps
from mvsformerpp.io.images import read_image
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import write_ply


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
         device: str = "cpu", quiet: bool = False, mask_dir: str | Path | None = None,
         normals: bool = True) -> Path:
    """Fuse the depth maps of ``folder`` into ``out_ply`` (default ``folder/fused.ply``); returns its path.

    ``mask_dir``: object masks (:mod:`mvsformerpp.io.masks`); depths outside them are dropped before
    fusion. ``normals``: store per-point normals and confidences from the depth maps
    (:mod:`mvsformerpp.fusion.normals`).
    """
    folder = Path(folder)
    out_ply = Path(out_ply) if out_ply is not None else folder / "fused.ply"
    config = config or FusionConfig()
    scene, depths, confs, images = load_depth_folder(folder)
    if mask_dir is not None:
        depths = apply_masks(folder, scene, depths, mask_dir)
    t0 = time.perf_counter()
    with tqdm(total=len(scene), desc=f"Fusion ({config.method})", unit="view", disable=quiet) as bar:
        xyz, rgb = fuse_depth_maps(scene, depths, confs, images, config, device, progress=lambda r: bar.update(1))
    if len(xyz) == 0:
        warnings.warn(
            "fusion kept no point: the depth maps disagree everywhere or all confidences are below "
            f"{config.conf_threshold} (re-run `mvsformerpp fuse {folder}` with a lower --conf, "
            "--num-consistent 1 or --fusion dynamic); "
            "writing an empty point cloud", stacklevel=2)
    point_normals, extra = None, None
    if normals:
        from mvsformerpp.fusion import make_views
        from mvsformerpp.fusion.normals import point_attributes

        point_normals, confidence = point_attributes(xyz, make_views(scene, depths, confs, images, device))
        extra = {"confidence": confidence}
    write_ply(out_ply, xyz, rgb, normals=point_normals, extra=extra)
    if not quiet:
        print(f"{len(xyz):,} points in {time.perf_counter() - t0:.1f} s -> {out_ply}")
    return out_ply


def apply_masks(folder: Path, scene, depths: list[np.ndarray], mask_dir: str | Path) -> list[np.ndarray]:
    """Depth maps with 0 outside the object masks (matched to the views by the photos' original names)."""
    import json

    from mvsformerpp.io.masks import load_masks

    names_file = folder / "views.json"
    original = json.loads(names_file.read_text()) if names_file.is_file() else {}
    names = [original.get(v.name, v.image_path.name) for v in scene.views]
    masks = load_masks(mask_dir, names, [d.shape for d in depths])
    return [np.where(m, d, 0).astype(d.dtype) for m, d in zip(masks, depths)]
