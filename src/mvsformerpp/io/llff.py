"""LLFF ``poses_bounds.npy`` (Mildenhall et al., SIGGRAPH 2019; the NeRF forward-facing captures).

Format: an ``[N, 17]`` float array, one row per photo of ``images/`` in name order (the photos COLMAP
registered). The first 15 numbers are a 3x5 matrix, row by row: columns 0-2 the camera-to-world rotation
with the camera's axes in the order (down, right, backwards), column 3 the camera centre, column 4
``(height, width, focal)`` in pixels of the photos the poses were computed at. The last two numbers are
the near and far z-depth of the scene seen by that view (percentiles of COLMAP's points). The principal
point is the image centre (LLFF keeps one pinhole focal length).

In this package's convention (x right, y down, z forward, world-to-camera): the camera-to-world rotation
is ``[c1, c0, -c2]`` of those columns, ``R`` its transpose, ``t = -R C``. Photos at another resolution than
``(width, height)`` (``images_4/`` style reductions, or a resized copy) keep the aspect ratio and get ``K``
scaled to them. Neighbours: :func:`~mvsformerpp.io.viewselect.neighbors_from_cameras`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.images import image_size, list_images
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.io.viewselect import set_neighbors_from_cameras

POSES_FILE = "poses_bounds.npy"


def read_poses_bounds(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(R [N,3,3] world-to-camera, t [N,3], hwf [N,3] (height, width, focal), bounds [N,2] near/far z)."""
    path = Path(path)
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise FormatError(f"not a readable .npy array ({e})", path) from e
    if arr.ndim != 2 or arr.shape[1] != 17 or len(arr) == 0:
        raise FormatError(f"an LLFF poses_bounds.npy holds an [N, 17] array, this one is {list(arr.shape)}", path)
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise FormatError("non-finite values in the poses", path)
    m = arr[:, :15].reshape(-1, 3, 5)
    c2w = np.stack([m[:, :, 1], m[:, :, 0], -m[:, :, 2]], axis=2)  # columns: right, down, forward
    R = np.transpose(c2w, (0, 2, 1))
    t = -np.einsum("nij,nj->ni", R, m[:, :, 3])
    return R, t, m[:, :, 4].copy(), arr[:, 15:17].copy()


def is_llff_scene(path: Path) -> bool:
    """Whether ``path`` is a ``poses_bounds.npy`` or a folder holding one."""
    return path.name == POSES_FILE if path.is_file() else (path / POSES_FILE).is_file()


def load_llff_scene(path: str | Path, num_neighbors: int = 10, image_dir: str = "images") -> Scene:
    """Load an LLFF capture: ``path`` is its folder or its ``poses_bounds.npy``; photos from ``image_dir``."""
    path = Path(path)
    root = path.parent if path.is_file() else path
    poses = root / POSES_FILE
    if not poses.is_file():
        raise InputError(f"no {POSES_FILE} here (an LLFF capture has it beside images/)", root)
    R, t, hwf, bounds = read_poses_bounds(poses)
    photos = list_images(root / image_dir)
    if len(photos) != len(R):
        raise InputError(f"{POSES_FILE} holds {len(R)} cameras but {image_dir}/ has {len(photos)} photos: the cameras "
                         "do not fit the images (one pose per photo, in name order)", root)
    views = []
    for i, photo in enumerate(photos):
        h0, w0, f = hwf[i]
        w, h = image_size(photo)
        s = w / w0
        if min(h0, w0, f) <= 0 or abs(h0 * s - h) > 1.0 + 0.002 * h:
            raise InputError(f"photo {photo.name} is {w}x{h} but its camera is for {w0:g}x{h0:g} photos (another "
                             "aspect ratio): the cameras do not fit the images", root)
        K = np.array([[f * s, 0, w / 2], [0, f * h / h0, h / 2], [0, 0, 1.0]])
        near, far = (float(b) for b in bounds[i])
        views.append(View(name=photo.stem, image_path=photo, width=w, height=h, K=K, R=R[i], t=t[i],
                          depth_min=near if 0 < near < far else None, depth_max=far if 0 < near < far else None))
    set_neighbors_from_cameras(views, num_neighbors)
    return Scene(views=views, root=root, source_format="llff")
