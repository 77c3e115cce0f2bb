"""``export``: a reconstruction as a COLMAP dense workspace, for COLMAP's and OpenMVS's tools.

Layout (what ``colmap image_undistorter`` + ``patch_match_stereo`` leave, so that ``colmap
stereo_fusion``, ``colmap poisson_mesher`` / ``delaunay_mesher`` and OpenMVS's ``InterfaceCOLMAP`` read
it as their own):

* ``images/NNNNNNNN.<ext>``: the photos the depth maps belong to (already undistorted: pinhole cameras);
* ``sparse/{cameras,images,points3D}.bin``: one ``PINHOLE`` camera per view, the poses, and a sample of
  depth-map points with their observations in every view whose depth agrees (COLMAP derives the
  overlapping views and depth ranges of its fusion from them);
* ``stereo/depth_maps/NAME.geometric.bin`` and ``.photometric.bin``: our depth maps (z-depth, 0 = none)
  in COLMAP's array format (:mod:`mvsformerpp.io.colmap_dense`); ``stereo/normal_maps/`` likewise
  (camera-frame normals from the depth maps, :func:`mvsformerpp.fusion.normals.normal_map`);
* ``stereo/fusion.cfg`` and ``stereo/patch-match.cfg``: the image list;
* ``cameras.ply``: the camera frustums as a mesh.

COLMAP's pixel convention (the top-left pixel's centre at (0.5, 0.5)) is this package's, so K is
written as it is. The workspace is built in a temporary folder beside the target and renamed into
place (:mod:`mvsformerpp.utils.output_tree`): an interrupted export leaves no half workspace, and the
old workspace that ``--overwrite`` replaces goes only once the new one is in place.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import torch

from mvsformerpp.fusion.normals import normal_map
from mvsformerpp.geometry.frustum import FRUSTUM_FACES, frustum_points
from mvsformerpp.io.colmap_dense import write_colmap_array
from mvsformerpp.io.colmap_model import (
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    ColmapPoint3D,
    rotmat_to_qvec,
    write_model,
)
from mvsformerpp.io.depth_folder import load_depth_folder
from mvsformerpp.io.output_folder import read_run_record, require_depth_maps
from mvsformerpp.io.ply import write_ply
from mvsformerpp.utils.file_kinds import CAMERA_FRUSTUMS, PLY_MARKER
from mvsformerpp.utils.output_guard import check_not_input, child
from mvsformerpp.utils.output_tree import claim_output_tree


def export_colmap(folder: str | Path, target: str | Path, overwrite: bool = False, quiet: bool = False) -> Path:
    """Write the reconstruction in ``folder`` as a COLMAP dense workspace ``target``; returns ``target``.

    ``target`` is new or empty, or with ``overwrite`` a workspace this command wrote; never the reconstruction,
    its input, or a folder holding either (:func:`~mvsformerpp.utils.output_tree.claim_output_tree`: the new
    workspace is complete before the old one goes).
    """
    folder, target = Path(folder), Path(target)
    recorded_input = (read_run_record(folder) or {}).get("input")
    inputs = [folder, *([recorded_input] if isinstance(recorded_input, str) else [])]
    check_not_input(target, inputs, "DIR")  # (before minutes of loading)
    scene, depths, _, photos = load_depth_folder(require_depth_maps(folder))
    inputs += sorted({str(Path(v.image_path).resolve().parent) for v in scene.views})  # the photos (links followed)
    with claim_output_tree(target, "export", inputs, overwrite, recognise=_earlier_workspace,
                           flag="DIR") as tmp:
        names = _write_workspace(tmp, scene, depths, photos)
    if not quiet:
        print(f"COLMAP workspace with {len(names)} images -> {target}\n"
              f"  fuse with COLMAP : colmap stereo_fusion --workspace_path {target} --output_path fused.ply\n"
              f"  OpenMVS          : InterfaceCOLMAP -i {target} -o scene.mvs --image-folder {target}/images")
    return target


def _write_workspace(root: Path, scene, depths, photos) -> list[str]:
    """The workspace of the module docstring in the empty folder ``root``; returns the photos' names."""
    for sub in ("images", "sparse", "stereo/depth_maps", "stereo/normal_maps", "stereo/consistency_graphs"):
        (root / sub).mkdir(parents=True)
    cameras, images, names = {}, {}, []
    for i, (view, depth) in enumerate(zip(scene.views, depths)):
        name = f"{view.name}{view.image_path.suffix.lower()}"
        names.append(name)
        _link_or_copy(view.image_path, child(root / "images", name, "view name"))
        K = view.K
        cameras[i + 1] = ColmapCamera(i + 1, "PINHOLE", view.width, view.height,
                                      np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]))
        images[i + 1] = ColmapImage(i + 1, rotmat_to_qvec(view.R), view.t.copy(), i + 1, name)
        h, w = depth.shape
        Kd = np.diag([w / view.width, h / view.height, 1.0]) @ K
        normals = normal_map(torch.from_numpy(np.ascontiguousarray(depth)), torch.from_numpy(Kd)).numpy()
        for kind in ("geometric", "photometric"):
            write_colmap_array(root / "stereo" / "depth_maps" / f"{name}.{kind}.bin", depth)
            write_colmap_array(root / "stereo" / "normal_maps" / f"{name}.{kind}.bin", normals)
    points = sparse_points(scene, depths, photos, images)
    write_model(ColmapModel(cameras, images, points), root / "sparse", ext=".bin")
    (root / "stereo" / "fusion.cfg").write_text("".join(f"{n}\n" for n in names))
    (root / "stereo" / "patch-match.cfg").write_text("".join(f"{n}\n__auto__, 20\n" for n in names))
    write_frustums(scene, root / "cameras.ply")
    return names


def _earlier_workspace(path: Path) -> bool:
    """A workspace an earlier version of this command wrote (before the marker): exactly its layout, with the
    camera mesh that only this command writes."""
    names = {p.name for p in path.iterdir()}
    frustums = path / "cameras.ply"
    if names != {"images", "sparse", "stereo", "cameras.ply"} or not frustums.is_file():
        return False
    with open(frustums, "rb") as f:
        return (PLY_MARKER + "\n").encode() in f.read(4096)


def sparse_points(scene, depths, photos, images: dict, per_view: int = 2000, tolerance: float = 0.01,
                  seed: int = 0) -> dict:
    """COLMAP 3-D points from the depth maps: ``per_view`` random pixels of each view, back-projected, each
    observed by every view that sees it (projected depth within ``tolerance`` relative of that view's
    depth there). Fills ``images[k].xys`` / ``point3D_ids`` (image k = view k - 1) and returns the points."""
    rng = np.random.default_rng(seed)
    xyz, rgb = [], []
    for view, depth, photo in zip(scene.views, depths, photos):
        h, w = depth.shape
        valid = np.flatnonzero(depth.reshape(-1) > 0)
        pick = rng.choice(valid, min(per_view, len(valid)), replace=False) if len(valid) else valid
        y, x = np.divmod(pick, w)
        Kd = np.diag([w / view.width, h / view.height, 1.0]) @ view.K
        d = depth.reshape(-1)[pick]
        cam = np.stack([x + 0.5, y + 0.5, np.ones_like(d)], 1) @ np.linalg.inv(Kd).T * d[:, None]
        xyz.append((cam - view.t) @ view.R)
        img = np.asarray(photo)
        rgb.append(img[(y * img.shape[0]) // h, (x * img.shape[1]) // w, :3])
    xyz, rgb = np.concatenate(xyz), np.concatenate(rgb)
    tracks: list[list[tuple[int, int]]] = [[] for _ in range(len(xyz))]
    for k, (view, depth) in enumerate(zip(scene.views, depths)):
        cam = xyz @ view.R.T + view.t
        z = cam[:, 2]
        uv = cam @ view.K.T
        u, v = uv[:, 0] / np.maximum(z, 1e-12), uv[:, 1] / np.maximum(z, 1e-12)
        h, w = depth.shape
        inside = (z > 0) & (u >= 0) & (u < view.width) & (v >= 0) & (v < view.height)
        ui = np.clip((u * w / view.width).astype(np.int64), 0, w - 1)
        vi = np.clip((v * h / view.height).astype(np.int64), 0, h - 1)
        dz = depth[vi, ui]
        seen = np.flatnonzero(inside & (dz > 0) & (np.abs(dz - z) <= tolerance * dz))
        image = images[k + 1]
        image.xys = np.stack([u[seen], v[seen]], 1)
        image.point3D_ids = seen.astype(np.int64) + 1
        for j, p in enumerate(seen):
            tracks[p].append((k + 1, j))
    points = {}
    for p, track in enumerate(tracks):
        if len(track) >= 2:
            t = np.array(track, dtype=np.int64)
            points[p + 1] = ColmapPoint3D(p + 1, xyz[p], rgb[p].astype(np.uint8), 0.0, t[:, 0], t[:, 1])
    for image in images.values():  # observations of points seen only once stay untriangulated
        image.point3D_ids = np.array([i if i in points else -1 for i in image.point3D_ids], dtype=np.int64)
    return points


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def write_frustums(scene, path: Path, size: float | None = None) -> Path:
    """The cameras of ``scene`` as a PLY mesh of frustums (image corners at depth ``size``; default: a
    quarter of the median near depth, or of the median distance between neighbouring cameras)."""
    if size is None:
        near = [v.depth_min for v in scene.views if v.depth_min]
        if near:
            size = 0.25 * float(np.median(near))
        else:
            centres = np.stack([v.center for v in scene.views])
            gaps = np.linalg.norm(centres[1:] - centres[:-1], axis=1)
            size = float(np.median(gaps)) if len(gaps) and np.median(gaps) > 0 else 1.0
    verts, faces = [], []
    for i, v in enumerate(scene.views):
        verts.append(frustum_points(v.K, v.R, v.t, v.width, v.height, size))
        faces.append(FRUSTUM_FACES + 5 * i)
    colors = np.tile(np.array([[230, 60, 40]], np.uint8), (5 * len(scene.views), 1))
    write_ply(path, np.concatenate(verts).astype(np.float32), colors, faces=np.concatenate(faces),
              kind=CAMERA_FRUSTUMS)
    return path
