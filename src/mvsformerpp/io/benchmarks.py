"""Benchmark data set layouts as Scenes: DTU training, BlendedMVS, Tanks and Temples (MVSNet style).

All three are MVSNet cam files + pair.txt in other folder arrangements; each loader lists
(view id, cam file, photo, GT depth, mask) and builds the Scene with the MVSNet helpers.

DTU training (the MVSNet ``dtu_training`` release; ``scanN`` = scan name, ``vid`` = view 0..48)::

    Cameras/pair.txt
    Cameras/train/{vid:08d}_cam.txt              K for the 640x512 photos' 160x128 depth maps (x4)
    Cameras/{vid:08d}_cam.txt                    K for the 1600x1200 raw photos
    Rectified/scanN_train/rect_{vid+1:03d}_{light}_r5000.png         640x512, light 0..6
    Rectified_raw/scanN/rect_{vid+1:03d}_{light}_r5000.png           1600x1200 (optional)
    Depths/scanN_train/depth_map_{vid:04d}.pfm  (+ depth_visual_{vid:04d}.png mask)   160x128
    Depths_raw/scanN/depth_map_{vid:04d}.pfm    (+ depth_visual_{vid:04d}.png mask)   1600x1200

BlendedMVS (``PID`` = 24-hex-digit scene id; some releases nest ``PID/PID/PID``)::

    PID/blended_images/{vid:08d}.jpg (+ _masked.jpg)   PID/cams/{vid:08d}_cam.txt   PID/cams/pair.txt
    PID/rendered_depth_maps/{vid:08d}.pfm

Tanks and Temples (MVSNet preprocessed ``intermediate``/``advanced``)::

    Scene/images/{vid:08d}.jpg   Scene/cams/{vid:08d}_cam.txt (or cams_1/)   Scene/pair.txt
    short_range_cameras/cams_{scene lower case}/{vid:08d}_cam.txt   (beside the scene folders)
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from mvsformerpp.errors import InputError
from mvsformerpp.io.images import find_image
from mvsformerpp.io.mvsnet import (
    DEFAULT_NUM_DEPTH,
    DepthFormat,
    cam_files,
    report_scaling,
    set_neighbors,
    view_from_cam,
)
from mvsformerpp.io.scene import Scene, View

_DTU_SCAN_RE = re.compile(r"^(scan\d+)(?:_train)?$")


def _first_dir(*cands: Path) -> Path | None:
    return next((c for c in cands if c.is_dir()), None)


def _first_file(*cands: Path) -> Path | None:
    return next((c for c in cands if c.is_file()), None)


# ---------------------------------------------------------------------------------------------- DTU


def is_dtu_root(path: Path) -> bool:
    return (path / "Cameras").is_dir() and ((path / "Rectified").is_dir() or (path / "Rectified_raw").is_dir())


def list_dtu_scans(root: str | Path) -> list[str]:
    """Scan names (``scan1``, ...) with photos under ``Rectified/`` or ``Rectified_raw/``, sorted by number."""
    root = Path(root)
    names = set()
    for sub in ("Rectified", "Rectified_raw"):
        if (root / sub).is_dir():
            for p in (root / sub).iterdir():
                m = _DTU_SCAN_RE.match(p.name)
                if m and p.is_dir():
                    names.add(m.group(1))
    return sorted(names, key=lambda s: int(s[4:]))


def load_dtu_scene(
    root: str | Path,
    scan: str | int | None = None,
    light: int = 3,
    resolution: Literal["auto", "train", "raw"] = "auto",
    depth_format: DepthFormat = "auto",
    num_depth: int = DEFAULT_NUM_DEPTH,
    interval_scale: float = 1.0,
    num_neighbors: int = 10,
) -> Scene:
    """One scan of the DTU training layout (module docstring) as a Scene.

    ``scan`` is ``"scan1"`` or ``1``; it may be left out when the layout holds one scan. ``light`` picks
    the lighting (0..6; 3 is the usual choice). ``resolution="train"`` uses the 640x512 photos with the
    ``Cameras/train`` cams (K scaled x4 to the photos) and the 160x128 GT depth; ``"raw"`` the 1600x1200
    photos with ``Cameras/`` and ``Depths_raw``; ``"auto"`` prefers ``train`` when its photos exist.
    """
    root = Path(root)
    if not is_dtu_root(root):
        raise InputError("not a DTU training layout (expected Cameras/ and Rectified/ or Rectified_raw/)", root)
    scan = _dtu_scan(root, scan)
    image_dir, cam_dir, depth_dir = _dtu_folders(root, scan, resolution)
    cams = cam_files(cam_dir)
    if not cams:
        raise InputError("no NNNNNNNN_cam.txt files: the scene is empty", cam_dir)
    views: list[View] = []
    ids, skipped, scales = [], set(), []
    for vid, cam_path in cams.items():
        img = image_dir / f"rect_{vid + 1:03d}_{light}_r5000.png"
        if not img.is_file():
            skipped.add(vid)  # DTU cams cover 64 positions; scans have 49 photos
            continue
        v = view_from_cam(f"{vid:08d}", cam_path, img, depth_format, num_depth, interval_scale, scales)
        if depth_dir is not None:
            v.depth_gt_path = _first_file(depth_dir / f"depth_map_{vid:04d}.pfm")
            v.mask_path = _first_file(depth_dir / f"depth_visual_{vid:04d}.png")
        views.append(v)
        ids.append(vid)
    if not views:
        raise InputError(f"no photos rect_XXX_{light}_r5000.png matching the cams (light {light})", image_dir)
    report_scaling(image_dir, scales)
    pair = _first_file(root / "Cameras" / "pair.txt", cam_dir / "pair.txt")
    set_neighbors(views, ids, pair, num_neighbors, skipped)
    return Scene(views=views, root=root, source_format="dtu")


def _dtu_scan(root: Path, scan: str | int | None) -> str:
    """The scan's name (``scanN``) among the scans with photos under ``root``; the only one when None."""
    scans = list_dtu_scans(root)
    if scan is None:
        if len(scans) != 1:
            raise InputError(f"the DTU layout holds {len(scans)} scans ({', '.join(scans[:8])}"
                             f"{', ...' if len(scans) > 8 else ''}); choose one with scan=", root)
        scan = scans[0]
    scan = f"scan{scan}" if isinstance(scan, int) or str(scan).isdigit() else str(scan)
    if scan not in scans:
        raise InputError(f"no photos for {scan} (scans here: {', '.join(scans) or 'none'})", root)
    return scan


def _dtu_folders(root: Path, scan: str, resolution: str) -> tuple[Path, Path, Path | None]:
    """(photos, cams, ground-truth depths or None) of ``scan`` at ``resolution`` (see :func:`load_dtu_scene`)."""
    train_dir = root / "Rectified" / f"{scan}_train"
    if not train_dir.is_dir():
        train_dir = root / "Rectified" / scan
    if resolution == "auto":
        resolution = "train" if train_dir.is_dir() else "raw"
    if resolution == "train":
        image_dir = train_dir
        cam_dir = _first_dir(root / "Cameras" / "train", root / "Cameras")
        depth_dir = _first_dir(root / "Depths" / f"{scan}_train", root / "Depths" / scan)
    else:
        image_dir = root / "Rectified_raw" / scan
        cam_dir = root / "Cameras"
        depth_dir = _first_dir(root / "Depths_raw" / scan)
    if not image_dir.is_dir():
        raise InputError(f"no {resolution} photos for {scan} (expected {image_dir.relative_to(root)}/)", root)
    return image_dir, cam_dir, depth_dir


# ---------------------------------------------------------------------------------------- BlendedMVS


def blended_scene_dir(path: str | Path) -> Path | None:
    """The folder holding ``blended_images/`` and ``cams/`` at ``path`` or nested ``path/PID[/PID]``."""
    path = Path(path)
    for cand in (path, path / path.name, path / path.name / path.name):
        if (cand / "blended_images").is_dir() and (cand / "cams").is_dir():
            return cand
    return None


def load_blended_scene(
    path: str | Path,
    depth_format: DepthFormat = "auto",
    num_depth: int = DEFAULT_NUM_DEPTH,
    interval_scale: float = 1.0,
    num_neighbors: int = 10,
) -> Scene:
    """One BlendedMVS scene (``PID`` folder, module docstring); GT depth from ``rendered_depth_maps/``."""
    scene_dir = blended_scene_dir(path)
    if scene_dir is None:
        raise InputError("not a BlendedMVS scene (expected blended_images/ and cams/)", path)
    cams = cam_files(scene_dir / "cams")
    if not cams:
        raise InputError("no NNNNNNNN_cam.txt files: the scene is empty", scene_dir / "cams")
    views, scales = [], []
    for vid, cam_path in cams.items():
        img = scene_dir / "blended_images" / f"{vid:08d}.jpg"
        img = img if img.is_file() else find_image(scene_dir / "blended_images", f"{vid:08d}")
        if img is None:
            raise InputError(f"no photo for camera {cam_path.name}", scene_dir / "blended_images")
        v = view_from_cam(f"{vid:08d}", cam_path, img, depth_format, num_depth, interval_scale, scales)
        v.depth_gt_path = _first_file(scene_dir / "rendered_depth_maps" / f"{vid:08d}.pfm")
        views.append(v)
    report_scaling(scene_dir, scales)
    pair = _first_file(scene_dir / "cams" / "pair.txt", scene_dir / "pair.txt")
    set_neighbors(views, list(cams), pair, num_neighbors)
    return Scene(views=views, root=scene_dir, source_format="blendedmvs")


# ---------------------------------------------------------------------------------- Tanks and Temples


def tnt_cam_dir(scene_dir: Path, short_range: bool = False) -> Path | None:
    """The cams folder of a TnT scene: ``short_range_cameras/cams_<scene>`` beside it, ``cams/`` or ``cams_1/``."""
    if short_range:
        for base in (scene_dir.parent, scene_dir):
            for name in (scene_dir.name.lower(), scene_dir.name):
                cand = base / "short_range_cameras" / f"cams_{name}"
                if cand.is_dir():
                    return cand
        return None
    return _first_dir(scene_dir / "cams", scene_dir / "cams_1")


def load_tnt_scene(
    scene_dir: str | Path,
    short_range: bool = False,
    depth_format: DepthFormat = "auto",
    num_depth: int = DEFAULT_NUM_DEPTH,
    interval_scale: float = 1.0,
    num_neighbors: int = 10,
) -> Scene:
    """A Tanks-and-Temples scene in the MVSNet preprocessed layout; ``short_range`` picks the
    ``short_range_cameras`` (tighter depth ranges) instead of ``cams/``. TnT has no GT depth."""
    scene_dir = Path(scene_dir)
    cam_dir = tnt_cam_dir(scene_dir, short_range)
    if cam_dir is None:
        where = "short_range_cameras/cams_<scene>/ beside the scene" if short_range else "cams/ or cams_1/"
        raise InputError(f"no Tanks-and-Temples cameras (looked for {where})", scene_dir)
    if not (scene_dir / "images").is_dir():
        raise InputError("no images/ folder", scene_dir)
    cams = cam_files(cam_dir)
    if not cams:
        raise InputError("no NNNNNNNN_cam.txt files: the scene is empty", cam_dir)
    views, scales = [], []
    for vid, cam_path in cams.items():
        img = find_image(scene_dir / "images", f"{vid:08d}")
        if img is None:
            raise InputError(f"no photo for camera {cam_path.name}", scene_dir / "images")
        views.append(view_from_cam(f"{vid:08d}", cam_path, img, depth_format, num_depth, interval_scale, scales))
    report_scaling(scene_dir, scales)
    set_neighbors(views, list(cams), _first_file(scene_dir / "pair.txt", cam_dir / "pair.txt"), num_neighbors)
    return Scene(views=views, root=scene_dir, source_format="tnt")
