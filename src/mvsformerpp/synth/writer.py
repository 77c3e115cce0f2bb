"""Write synthetic scenes in the MVSNet layout with ground truth."""

from __future__ import annotations

import inspect
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from mvsformerpp.errors import InputError
from mvsformerpp.io.mvsnet import MVSNetCam, write_cam, write_pair
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.io.ply import write_ply
from mvsformerpp.synth.render import centred_window, render_view, sensor_depth_range, sensor_points
from mvsformerpp.synth.scenes import random_scene
from mvsformerpp.utils.atomic import atomic_open, atomic_write_text, current_umask
from mvsformerpp.utils.file_kinds import GT_SURFACE
from mvsformerpp.utils.output_guard import claim_output_folder

SCENE_RECORD = "scene.json"
"""Written last: a scene folder without it is unfinished."""


def save_png(path: Path, array: np.ndarray) -> None:
    """An uint8 image as PNG, written atomically."""
    with atomic_open(path, "wb") as f:
        Image.fromarray(array).save(f, format="PNG")


def _pairs(centers: np.ndarray, num_neighbors: int) -> dict:
    """Neighbours by camera distance (the arc order), scores decreasing with distance."""
    pairs = {}
    for i, c in enumerate(centers):
        dist = np.linalg.norm(centers - c, axis=1)
        order = [j for j in np.argsort(dist, kind="stable") if j != i][:num_neighbors]
        pairs[i] = [(int(j), float(1.0 / (1e-3 + dist[j]))) for j in order]
    return pairs


def generate_scene(out_dir: str | Path, seed: int = 0, num_views: int = 7, height: int = 256, width: int = 320,
                   num_objects: int | None = None, gt_points: int = 200_000, style: str = "classic",
                   sensor_width: tuple[float, float] | None = None, detail: float = 0.0,
                   layout: str | None = None, plain_walls: float = 0.0, textures: str | None = None) -> Path:
    """Render a scene of ``style`` (see :func:`random_scene`) and write it (deterministic for a seed):

    ``images/NNNNNNNN.png``, ``cams/NNNNNNNN_cam.txt`` (4-number depth line from the GT depth range),
    ``pair.txt``, ``depth_gt/NNNNNNNN.pfm`` (exact z-depth), ``masks/NNNNNNNN.png`` (255 = valid
    depth), ``gt_surface.ply`` (coloured points on the visible surfaces) and ``scene.json``.
    ``sensor_width``: the views are windows of larger photos (see :func:`random_scene`), each written as a
    photo of its own (:func:`~mvsformerpp.synth.render.centred_window`: the long focal length, the
    principal point in the middle); their cam files hold the whole photo's depth range joined with the
    view's, as a real crop's would. ``detail``: strength of the fine surface detail (see
    :func:`random_scene`). ``layout``, ``plain_walls``: the ``train`` style's layout and share of painted
    walls, ``textures`` its texture library (:func:`random_scene`).

    The folder is claimed by the output guard (:func:`~mvsformerpp.utils.output_guard.claim_output_folder`):
    new or empty, or the output of an earlier call with the same settings, which this completes (the scene
    is whole once ``scene.json``, written last, is there; every file is written atomically).
    """

    settings = dict(seed=seed, num_views=num_views, height=height, width=width, num_objects=num_objects,
                    gt_points=gt_points, style=style, sensor_width=sensor_width, detail=detail, layout=layout,
                    plain_walls=plain_walls, textures=textures)
    with claim_output_folder(out_dir, kind="synth", settings={"scenes": 1, **settings}, flag="OUT") as out:
        if not (out / SCENE_RECORD).is_file():
            write_scene(out, **settings)
    return Path(out_dir)


def write_scene(out: Path, seed: int, num_views: int, height: int, width: int, num_objects: int | None,
                gt_points: int, style: str, sensor_width: tuple[float, float] | None, detail: float,
                layout: str | None, plain_walls: float, textures: str | None) -> None:
    """Render and write one scene into the folder ``out`` (see :func:`generate_scene`; ``scene.json`` last)."""
    scene = random_scene(seed, num_views, height, width, num_objects, style=style, sensor_width=sensor_width,
                         detail=detail, layout=layout, plain_walls=plain_walls, textures=textures)
    photo_points = [sensor_points(scene, cam) for cam in scene.cameras]
    if sensor_width is not None:  # windows as photos of their own (principal points in the middle)
        scene.cameras = [centred_window(cam, width, height) for cam in scene.cameras]
    all_pts, all_rgb = [], []
    for i, cam in enumerate(scene.cameras):
        image, depth, pts = render_view(scene, cam)
        valid = depth > 0
        if not valid.any():
            raise InputError(f"synthetic scene seed {seed} ({style}): view {i} sees nothing; use another seed")
        stem = f"{i:08d}"
        save_png(out / "images" / f"{stem}.png", image)
        save_png(out / "masks" / f"{stem}.png", (valid * 255).astype(np.uint8))
        write_pfm(out / "depth_gt" / f"{stem}.pfm", depth)
        near, far = float(depth[valid].min()), float(depth[valid].max())
        photo = sensor_depth_range(scene, cam, points=photo_points[i]) if len(photo_points[i]) else None
        if photo is not None:
            near, far = min(near, photo[0]), max(far, photo[1])
        dmin, dmax = near * 0.95, far * 1.05
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = cam.R, cam.t
        write_cam(out / "cams" / f"{stem}_cam.txt",
                  MVSNetCam(E, cam.K, dmin, dmax, (dmax - dmin) / 191, 192))
        all_pts.append(pts[valid])
        all_rgb.append(image[valid])
    write_pair(out / "pair.txt", _pairs(np.stack([c.center for c in scene.cameras]), min(10, num_views - 1)))
    pts, rgb = np.concatenate(all_pts), np.concatenate(all_rgb)
    if len(pts) > gt_points:
        keep = np.random.default_rng(seed).choice(len(pts), gt_points, replace=False)
        keep.sort()
        pts, rgb = pts[keep], rgb[keep]
    write_ply(out / "gt_surface.ply", pts.astype(np.float32), rgb, kind=GT_SURFACE)
    atomic_write_text(out / SCENE_RECORD, json.dumps(
        {"seed": seed, "style": style, "num_views": num_views, "height": height, "width": width,
         "sensor_width": None if sensor_width is None else [float(v) for v in sensor_width],
         "detail": float(detail), "layout": scene.meta.get("layout"), "plain_walls": float(plain_walls),
         "surfaces": [type(s.shape).__name__ + ":" + s.texture for s in scene.surfaces]}, indent=2))


_SCENE_DEFAULTS = {k: v.default for k, v in inspect.signature(generate_scene).parameters.items()
                   if k not in ("out_dir", "seed")}
"""The settings of a scene besides its seed, with :func:`generate_scene`'s defaults."""


def generate_dataset(out_dir: str | Path, num_scenes: int, seed: int = 0, **kwargs) -> Path:
    """Many scenes, ``scene_0000/`` ... in the MVSNet layout, plus ``scenes.txt`` listing them (scene k from seed
    ``seed + 1000 k``; ``kwargs``: those of :func:`generate_scene`).

    Resumable as :func:`generate_scene` is: a scene is rendered into a temporary folder and renamed into place
    when whole, so a rerun with the same settings renders only the scenes still missing.
    """

    unknown = set(kwargs) - set(_SCENE_DEFAULTS)
    if unknown:
        raise TypeError(f"generate_dataset() got unexpected keyword arguments {sorted(unknown)}")
    kwargs = {**_SCENE_DEFAULTS, **kwargs}  # (the record names every setting: a rerun compares like with like)
    settings = {"scenes": num_scenes, "seed": seed, **kwargs}
    with claim_output_folder(out_dir, kind="synth", settings=settings, flag="OUT") as out:
        names = [f"scene_{k:04d}" for k in range(num_scenes)]
        for k, name in enumerate(names):
            if (out / name).is_dir():
                continue
            staging = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".tmp", dir=out))
            try:
                write_scene(staging, seed=seed + 1000 * k, **kwargs)
                os.chmod(staging, 0o777 & ~current_umask())
                os.rename(staging, out / name)
            except BaseException:
                shutil.rmtree(staging, ignore_errors=True)
                raise
        atomic_write_text(out / "scenes.txt", "\n".join(names) + "\n")
    return Path(out_dir)
