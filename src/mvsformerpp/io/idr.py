"""IDR / NeuS ``cameras_sphere.npz`` (Yariv et al., NeurIPS 2020; Wang et al., NeurIPS 2021).

Format: an ``.npz`` with, for every photo ``i`` of ``image/`` (NeuS) or ``images/`` in name order,
``world_mat_i``: the 4x4 projection ``[K [R | t]; 0 0 0 1]`` from world to pixel coordinates, and
``scale_mat_i``: the 4x4 similarity that maps the unit sphere around the object into the world
(``X = scale_mat @ X_unit``), the same for every view. ``camera_mat_i`` and the ``*_inv_i`` entries are
ignored. Older IDR data name the file ``cameras.npz``.

``K``, ``R`` and ``t`` come from the RQ decomposition of ``world_mat``'s left 3x3 block (``K`` upper
triangular with positive diagonal, ``R`` a rotation). The depth range of a view is the z-extent of that
sphere, ``z_c -/+ r`` for its centre's depth ``z_c`` and radius ``r`` (clamped to stay in front of the
camera); without ``scale_mat`` the views get no range. The world frame is the data's own (DTU: mm).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.images import image_size, list_images
from mvsformerpp.io.mvsnet import image_scale_factor
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.io.viewselect import set_neighbors_from_cameras

CAMERA_FILES = ("cameras_sphere.npz", "cameras.npz")
IMAGE_DIRS = ("image", "images")


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K, R, t) with ``P ~ K [R | t]`` for a 3x4 camera matrix: K upper triangular, K[2, 2] = 1, positive
    diagonal, R a rotation (det +1)."""
    # (imported here: io.detect, which the command line loads to build its flags, imports this module, and
    # scipy.linalg takes about 0.35 s to import)
    from scipy.linalg import rq

    P = np.asarray(P, dtype=np.float64)[:3, :4]
    if np.linalg.det(P[:, :3]) < 0:  # the overall sign of a homogeneous matrix is free
        P = -P
    K, R = rq(P[:, :3])
    signs = np.diag(np.sign(np.diag(K)))  # K's diagonal positive; R absorbs the signs (S S = I)
    K, R = K @ signs, signs @ R
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def find_camera_file(path: str | Path) -> Path | None:
    """The IDR camera file at ``path`` or inside the folder ``path``; None if there is none."""
    path = Path(path)
    if path.is_file():
        return path if path.name in CAMERA_FILES else None
    return next((path / n for n in CAMERA_FILES if (path / n).is_file()), None)


def is_idr_scene(path: Path) -> bool:
    """Whether ``path`` is an IDR camera file or a folder holding one."""
    return find_camera_file(path) is not None


def load_idr_scene(path: str | Path, num_neighbors: int = 10) -> Scene:
    """Load an IDR/NeuS scene: ``path`` is its folder or its camera file."""
    cam_file = find_camera_file(path)
    if cam_file is None:
        raise InputError(f"no IDR camera file ({' or '.join(CAMERA_FILES)}) here", path)
    root = cam_file.parent
    try:
        data = dict(np.load(cam_file, allow_pickle=False))
    except (OSError, ValueError) as e:
        raise FormatError(f"not a readable .npz archive ({e})", cam_file) from e
    folder = next((root / d for d in IMAGE_DIRS if list_images(root / d)), None)
    if folder is None:
        raise InputError(f"no photos in {' or '.join(d + '/' for d in IMAGE_DIRS)} beside {cam_file.name}", root)
    photos = list_images(folder)
    n = sum(1 for k in data if k.startswith("world_mat_") and not k.startswith("world_mat_inv"))
    if n != len(photos) or any(f"world_mat_{i}" not in data for i in range(n)):
        raise InputError(f"{cam_file.name} holds {n} cameras (world_mat_0 ..) but {folder.name}/ has {len(photos)} "
                         "photos: the cameras do not fit the images (one camera per photo, in name order)", root)
    views = []
    for i, photo in enumerate(photos):
        P = data[f"world_mat_{i}"]
        if P.shape not in ((4, 4), (3, 4)) or not np.isfinite(P).all():
            raise FormatError(f"world_mat_{i} must be a finite 3x4 or 4x4 matrix, got shape {list(P.shape)}", cam_file)
        K, R, t = decompose_projection(P)
        w, h = image_size(photo)
        K[:2] *= image_scale_factor(K, w, h, photo)
        near = far = None
        S = data.get(f"scale_mat_{i}")
        if S is not None:
            z = float((R @ S[:3, 3] + t)[2])
            r = float(abs(np.linalg.det(S[:3, :3])) ** (1 / 3))
            if z > 0:
                near, far = max(z - r, 0.05 * z), z + r
        views.append(View(name=photo.stem, image_path=photo, width=w, height=h, K=K, R=R, t=t,
                          depth_min=near, depth_max=far))
    set_neighbors_from_cameras(views, num_neighbors)
    return Scene(views=views, root=root, source_format="idr")
