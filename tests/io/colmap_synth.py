"""A small synthetic COLMAP model with exact geometry, shared by the COLMAP and detection tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from mvsformerpp.io.colmap_model import ColmapCamera, ColmapImage, ColmapModel, ColmapPoint3D, rotmat_to_qvec


def look_at(center: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World-to-camera rotation of a camera at ``center`` looking at ``target`` (y down)."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def synthetic_model(n_views=6, n_points=300, width=64, height=48, seed=0, radius=4.0, model="PINHOLE",
                    params=None) -> ColmapModel:
    rng = np.random.default_rng(seed)
    f = 60.0
    cam_params = params if params is not None else [f, f, width / 2, height / 2]
    cameras = {1: ColmapCamera(1, model, width, height, np.asarray(cam_params, float))}
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1]])
    pts = rng.uniform(-1, 1, size=(n_points, 3))
    images, tracks = {}, {i: [] for i in range(n_points)}
    for k in range(n_views):
        a = 2 * np.pi * k / n_views * 0.5  # half a ring: neighbours differ in angle
        c = np.array([radius * np.cos(a), radius * np.sin(a), 1.0 + 0.3 * k])
        R = look_at(c, np.zeros(3))
        t = -R @ c
        cam_pts = pts @ R.T + t
        uv = cam_pts @ K.T
        uv = uv[:, :2] / uv[:, 2:]
        # Each image sees the points inside its frame, minus a random 20 %.
        seen = np.flatnonzero((uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
                              & (rng.random(n_points) > 0.2))
        ids = np.concatenate([seen + 1, [-1]])  # plus one untriangulated observation
        xys = np.concatenate([uv[seen], [[1.5, 2.5]]])
        for j, p in enumerate(seen):
            tracks[p].append((k + 1, j))
        images[k + 1] = ColmapImage(k + 1, rotmat_to_qvec(R), t, 1, f"img_{k:02d}.png", xys, ids.astype(np.int64))
    points = {}
    for p, tr in tracks.items():
        if len(tr) >= 2:
            tr = np.array(tr, dtype=np.int64)
            points[p + 1] = ColmapPoint3D(p + 1, pts[p], rng.integers(0, 256, 3).astype(np.uint8),
                                          float(rng.random()), tr[:, 0], tr[:, 1])
    # Keep 2-D observations consistent: points with short tracks are untriangulated.
    for im in images.values():
        im.point3D_ids = np.array([i if i in points else -1 for i in im.point3D_ids], dtype=np.int64)
    return ColmapModel(cameras, images, points)


def write_photos(model: ColmapModel, image_dir: Path, scale: int = 1) -> None:
    image_dir.mkdir(parents=True, exist_ok=True)
    for im in model.images.values():
        cam = model.cameras[im.camera_id]
        Image.new("RGB", (cam.width * scale, cam.height * scale), (90, 120, 150)).save(image_dir / im.name)
