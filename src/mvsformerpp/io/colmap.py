"""COLMAP projects as MVS scenes: depth ranges and neighbours from the sparse points; undistortion.

Per image, the depth range comes from the z-depths of the sparse points it observes (as
colmap2mvsnet does, MVSNet repository): robust percentiles (1 % and 99 %) widened by a margin
(min x 0.75, max x 1.25). Neighbours use the MVSNet triangulation-angle score summed over shared
points (:mod:`mvsformerpp.io.viewselect`), top 10 by default.

K is taken from the camera parameters unchanged (COLMAP's principal point, as colmap2mvsnet does).
Distorted camera models must be undistorted first (:func:`undistort_colmap`, which needs pycolmap).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.io.colmap_model import (
    CAMERA_MODELS,
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    ColmapPoint3D,
    model_extension,
    read_model,
    write_model,
)
from mvsformerpp.io.images import image_size
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.io.viewselect import pair_scores_from_points, top_neighbors

log = logging.getLogger(__name__)

__all__ = [
    "CAMERA_MODELS", "ColmapCamera", "ColmapImage", "ColmapModel", "ColmapPoint3D", "depth_range_from_points",
    "find_colmap_model", "load_colmap_scene", "read_model", "undistort_colmap", "write_model",
]

# Where a COLMAP project keeps its model and photos, in the order they are tried.
MODEL_SUBDIRS = ("sparse/0", "sparse", "dense/sparse", "dense/0/sparse", ".")
IMAGE_SUBDIRS = ("images", "dense/images", "dense/0/images")


def find_colmap_model(project: str | Path) -> tuple[Path, Path | None]:
    """``(model_dir, image_dir)`` of a COLMAP project folder (or of a model folder itself).

    The model is looked for in ``sparse/0``, ``sparse``, ``dense/sparse``, ``dense/0/sparse`` and the
    folder itself, preferring one with an ``images/`` folder beside it: in a folder holding both a
    distorted sparse model without photos and an undistorted ``dense/{images,sparse}`` workspace (what
    structure from motion writes), ``dense/`` is the pair that belongs together. Photos are taken from
    ``images/`` beside the model, else the project's ``images/``, ``dense/images``, else ``images/`` beside
    the folder given (when it is the model itself); ``image_dir`` is None
    when no image folder is found.
    """
    project = Path(project)
    found = [project / sub for sub in MODEL_SUBDIRS if model_extension(project / sub)]
    if not found:
        raise InputError(
            "no COLMAP model found (looked for cameras/images/points3D .bin or .txt in "
            + ", ".join(f"{s}/" for s in MODEL_SUBDIRS) + ")",
            project,
        )

    def beside(model_dir: Path) -> list[Path]:
        near = [model_dir, model_dir.parent, model_dir.parent.parent]
        return [c / "images" for c in near if (c == project or project in c.parents) and (c / "images").is_dir()]

    model_dir = next((m for m in found if beside(m)), found[0])
    candidates = beside(model_dir) + [project / s for s in IMAGE_SUBDIRS]
    candidates += [model_dir.parent / "images", model_dir.parent.parent / "images"]  # a model folder given itself
    image_dir = next((c for c in candidates if c.is_dir()), None)
    return model_dir, image_dir


def sparse_point_depths(project: str | Path) -> dict[str, np.ndarray]:
    """``{image name: z-depths of the sparse points it observes}`` of a COLMAP project or model folder."""
    model = read_model(find_colmap_model(project)[0])
    out = {}
    for im in model.images.values():
        ids = [int(p) for p in im.point3D_ids if p >= 0 and int(p) in model.points3D]
        xyz = np.array([model.points3D[p].xyz for p in ids], dtype=np.float64).reshape(-1, 3)
        out[im.name] = (xyz @ im.R.T + im.tvec)[:, 2]
    return out


def depth_range_from_points(
    z: np.ndarray, percentiles: tuple[float, float] = (1.0, 99.0), margin: tuple[float, float] = (0.75, 1.25)
) -> tuple[float, float] | None:
    """Robust depth range of positive depths ``z``: (P_lo * margin_lo, P_hi * margin_hi); None if no z > 0."""
    z = np.asarray(z, dtype=np.float64)
    z = z[np.isfinite(z) & (z > 0)]
    if z.size == 0:
        return None
    lo, hi = np.percentile(z, percentiles)
    lo, hi = float(lo * margin[0]), float(hi * margin[1])
    if hi <= lo:  # a single point, or all at one depth
        hi = lo * 1.5 + 1e-9
    return lo, hi


def _undistorted_hint(cam: ColmapCamera) -> str:
    return (
        f"camera {cam.id} uses the distorted model {cam.model}: MVS needs undistorted (pinhole) images. "
        "Undistort the project first with mvsformerpp.io.colmap.undistort_colmap(project, out_dir) "
        "(needs pycolmap: pip install 'mvsformerpp[colmap]') or 'colmap image_undistorter', then load the "
        "undistorted folder"
    )


def load_colmap_scene(
    sparse_dir: str | Path,
    image_dir: str | Path | None = None,
    num_neighbors: int = 10,
    percentiles: tuple[float, float] = (1.0, 99.0),
    margin: tuple[float, float] = (0.75, 1.25),
) -> Scene:
    """Load a COLMAP sparse model (folder with cameras/images/points3D) and its photos as a Scene.

    ``sparse_dir`` may also be a project folder (see :func:`find_colmap_model`). Views are the model's
    images sorted by name. A photo whose size differs from its camera by an exact integer factor gets
    K scaled by that factor (with a warning); any other mismatch is an :class:`InputError`.
    """
    model_dir, found_images = find_colmap_model(sparse_dir)
    image_dir = Path(image_dir) if image_dir is not None else found_images
    if image_dir is None or not image_dir.is_dir():
        raise InputError("no image folder for this COLMAP model (give image_dir, or put the photos in images/)",
                         sparse_dir)
    model = read_model(model_dir)
    if not model.images:
        raise InputError("the COLMAP model has no registered images: the scene is empty", model_dir)
    for cam in model.cameras.values():
        if not cam.is_pinhole and any(im.camera_id == cam.id for im in model.images.values()):
            raise InputError(_undistorted_hint(cam), model_dir)

    images = sorted(model.images.values(), key=lambda im: im.name)
    if not model.points3D:
        raise InputError("the COLMAP model has no 3-D points (points3D is empty); neighbour views and depth ranges "
                         "come from them: run the triangulation / mapping again", model_dir)
    point_ids = np.array(sorted(model.points3D), dtype=np.int64)
    xyz = np.stack([model.points3D[p].xyz for p in point_ids]) if len(point_ids) else np.zeros((0, 3))
    views, visibility = [], []
    for im in images:
        path = image_dir / im.name
        if not path.is_file():
            raise InputError(f"photo {im.name} of the COLMAP model is missing from {image_dir}", path)
        w, h = image_size(path)
        K = _photo_intrinsics(model.cameras[im.camera_id], w, h, path)
        R = im.R
        ids = im.point3D_ids[im.point3D_ids >= 0]
        idx = np.searchsorted(point_ids, ids)
        if len(point_ids):
            idx = idx[(idx < len(point_ids)) & (point_ids[np.minimum(idx, len(point_ids) - 1)] == ids)]
        else:  # a model without 3-D points: no image sees any
            idx = idx[:0]
        visibility.append(idx)
        z = (xyz[idx] @ R.T + im.tvec)[:, 2]
        rng = depth_range_from_points(z, percentiles, margin)
        if rng is None:
            log.warning("%s: the image sees no sparse points; no depth range (give one explicitly)", im.name)
        views.append(View(name=im.name, image_path=path, width=w, height=h, K=K, R=R, t=im.tvec,
                          depth_min=rng[0] if rng else None, depth_max=rng[1] if rng else None))
    centers = np.stack([v.center for v in views])
    scores = pair_scores_from_points(centers, xyz, visibility)
    for v, nb in zip(views, top_neighbors(scores, num_neighbors)):
        v.neighbors = [j for j, _ in nb]
    return Scene(views=views, root=Path(sparse_dir), source_format="colmap")


def _photo_intrinsics(cam, w: int, h: int, path: Path) -> np.ndarray:
    """K of camera ``cam`` for its w x h photo: scaled when the photo is an exact integer factor larger or
    smaller (with a warning), else an :class:`InputError`."""
    if (w, h) == (cam.width, cam.height):
        return cam.K
    sx, sy = w / cam.width, h / cam.height
    exact = sx == sy and (sx == round(sx) or 1 / sx == round(1 / sx))
    if not exact:
        raise InputError(
            f"photo is {w}x{h} but its COLMAP camera {cam.id} is {cam.width}x{cam.height} (not an integer "
            "scale factor): use the photos the model was built from", path)
    K = cam.K.copy()
    K[:2] *= sx
    log.warning("%s: photo is %gx the size of its COLMAP camera; scaled K", path, sx)
    return K


def undistort_colmap(project: str | Path, out_dir: str | Path, max_image_size: int = -1) -> Path:
    """Undistort a COLMAP project with pycolmap into ``out_dir`` (``images/`` + ``sparse/``); return out_dir.

    Photos are resampled to pinhole cameras (PINHOLE model) as ``colmap image_undistorter`` does.
    ``max_image_size`` (>0) caps the longer side of the output. Needs the ``colmap`` extra.
    """
    try:
        import pycolmap
    except ImportError as e:
        raise MissingDependencyError("pycolmap", "colmap", "Undistorting COLMAP camera models") from e
    model_dir, image_dir = find_colmap_model(project)
    if image_dir is None:
        raise InputError("no image folder beside the COLMAP model (expected images/)", project)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    options = pycolmap.UndistortCameraOptions()
    if max_image_size > 0:
        options.max_image_size = max_image_size
    pycolmap.undistort_images(str(out_dir), str(model_dir), str(image_dir), output_type="COLMAP",
                              undistort_options=options)
    return out_dir
