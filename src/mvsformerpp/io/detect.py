"""Recognise a scene's layout from its files and load it: the one entry point for user-given scenes.

Layouts (names returned by :func:`detect_layout`):

``mvsnet``      folder with ``images/`` and ``cams/`` (or ``cams_1/``) of ``NNNNNNNN_cam.txt``, ``pair.txt``
``tnt``         the same, with ``short_range_cameras/`` beside it (Tanks and Temples, MVSNet preprocessed)
``dtu``         DTU training layout: ``Cameras/`` + ``Rectified/`` (or ``Rectified_raw/``)
``blendedmvs``  ``blended_images/`` + ``cams/`` (also nested ``PID/PID/PID``)
``colmap``      COLMAP project (``sparse/0``, ``sparse``, ``dense/sparse`` or the model files directly)
``middlebury``  a ``*_par.txt`` file or a folder holding one
``idr``         IDR / NeuS ``cameras_sphere.npz`` (or ``cameras.npz``) + ``image/`` (or ``images/``), or that file
``llff``        LLFF ``poses_bounds.npy`` + ``images/``, or that file
``images``      photos without cameras: not loadable here (structure from motion is needed first)
"""

from __future__ import annotations

from pathlib import Path

from mvsformerpp.errors import InputError
from mvsformerpp.io.benchmarks import (
    blended_scene_dir,
    is_dtu_root,
    load_blended_scene,
    load_dtu_scene,
    load_tnt_scene,
)
from mvsformerpp.io.colmap import find_colmap_model, load_colmap_scene
from mvsformerpp.io.colmap_model import model_extension
from mvsformerpp.io.idr import find_camera_file, load_idr_scene
from mvsformerpp.io.images import list_images
from mvsformerpp.io.llff import POSES_FILE, load_llff_scene
from mvsformerpp.io.middlebury import find_par_file, load_middlebury_scene
from mvsformerpp.io.mvsnet import DEFAULT_NUM_DEPTH, DepthFormat, cam_files, load_mvsnet_scene
from mvsformerpp.io.scene import Scene

LAYOUTS = ("mvsnet", "tnt", "dtu", "blendedmvs", "colmap", "middlebury", "idr", "llff", "images")

_LOOKED_FOR = (
    "an MVSNet folder (images/ + cams/NNNNNNNN_cam.txt [+ pair.txt]), a Tanks-and-Temples scene "
    "(the same + short_range_cameras/ beside it), a DTU training root (Cameras/ + Rectified/), a BlendedMVS "
    "scene (blended_images/ + cams/), a COLMAP project (sparse/0, sparse/ or cameras/images/points3D "
    ".bin/.txt, + images/), a Middlebury *_par.txt file or a folder holding one, an IDR/NeuS scene "
    "(cameras_sphere.npz + image/), an LLFF capture (poses_bounds.npy + images/)"
)

_MODEL_FILES = {f"{n}{e}" for n in ("cameras", "images", "points3D") for e in (".bin", ".txt")}


def mvsnet_cam_dir(path: Path) -> Path | None:
    for name in ("cams", "cams_1"):
        if (path / name).is_dir() and cam_files(path / name):
            return path / name
    return None


def _refuse_incomplete(path: Path) -> None:
    """Name what is missing from a folder that is almost a COLMAP model or an MVSNet scene."""
    from mvsformerpp.io.colmap import MODEL_SUBDIRS

    for sub in MODEL_SUBDIRS:
        folder = path / sub
        have = {n for n in ("cameras", "images", "points3D") for e in (".bin", ".txt")
                if (folder / f"{n}{e}").is_file()}
        if have and len(have) < 3:
            missing = sorted({"cameras", "images", "points3D"} - have)
            raise InputError(f"incomplete COLMAP model in {sub or '.'}/: {', '.join(missing)} (.bin or .txt) is "
                             "missing; a model needs cameras, images and points3D", path)
    if (path / "images").is_dir() and not list_images(path) and (
            (path / "pair.txt").is_file() or (path / "cams").is_dir()):
        raise InputError("this looks like an MVSNet scene but has no cam files (cams/NNNNNNNN_cam.txt beside "
                         "images/); add them, or give a folder of photos for structure-from-motion", path)


def detect_layout(path: str | Path) -> str:
    """The layout name of the scene at ``path`` (see the module docstring); InputError when none fits."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file or folder", path)
    if path.is_file():
        if path.name.endswith("_par.txt"):
            return "middlebury"
        if path.name in _MODEL_FILES and model_extension(path.parent):
            return "colmap"
        if path.name == "pair.txt":
            return detect_layout(path.parent)
        if find_camera_file(path) is not None:
            return "idr"
        if path.name == POSES_FILE:
            return "llff"
        raise InputError(f"cannot tell the scene layout from this file; give a folder or file holding {_LOOKED_FOR}",
                         path)
    if is_dtu_root(path):
        return "dtu"
    if blended_scene_dir(path) is not None:
        return "blendedmvs"
    if (path / "images").is_dir() and mvsnet_cam_dir(path) is not None:
        if (path.parent / "short_range_cameras").is_dir():
            return "tnt"
        return "mvsnet"
    try:
        find_colmap_model(path)
        return "colmap"
    except InputError:
        pass
    if find_par_file(path) is not None:
        return "middlebury"
    if find_camera_file(path) is not None:
        return "idr"
    if (path / POSES_FILE).is_file():
        return "llff"
    _refuse_incomplete(path)
    if list_images(path) or list_images(path / "images"):
        return "images"
    raise InputError(f"no scene found here; looked for {_LOOKED_FOR}", path)


def load_scene(
    path: str | Path,
    *,
    layout: str | None = None,
    depth_range: tuple[float, float] | None = None,
    num_neighbors: int | None = None,
    depth_format: DepthFormat = "auto",
    num_depth: int = DEFAULT_NUM_DEPTH,
    interval_scale: float = 1.0,
    scan: str | int | None = None,
    short_range: bool = False,
    image_dir: str | Path | None = None,
) -> Scene:
    """Load the scene at ``path`` in whatever supported layout it is (or the given ``layout``).

    Overrides: ``depth_range`` (min, max) for every view (the cam files' depth lines are then ignored);
    ``num_neighbors`` caps the neighbour lists (default 10); ``depth_format``/``num_depth``/
    ``interval_scale`` for MVSNet cam files (:mod:`mvsformerpp.io.mvsnet`); ``scan`` picks a DTU scan;
    ``short_range`` the Tanks-and-Temples short-range cameras; ``image_dir`` the photos of a COLMAP model.
    The scene is checked with ``Scene.validate(require_depth_range=False)``.
    """
    path = Path(path)
    layout = layout or detect_layout(path)
    if layout not in LAYOUTS:
        raise InputError(f"unknown layout {layout!r} (known: {', '.join(LAYOUTS)})", path)
    k = 10 if num_neighbors is None else int(num_neighbors)
    if k < 0:
        raise InputError(f"number of neighbours must be >= 0, got {k}")
    if depth_range is not None:
        lo, hi = (float(v) for v in depth_range)
        if not 0 < lo < hi:
            raise InputError(f"depth range {lo:g}..{hi:g} must satisfy 0 < min < max")
        depth_format = "none"
    cam_args = dict(depth_format=depth_format, num_depth=num_depth, interval_scale=interval_scale, num_neighbors=k)
    if layout == "images":
        raise InputError(
            "this folder holds photos but no cameras; multi-view stereo needs calibrated cameras. Run structure "
            "from motion first (the reconstruct pipeline does it with COLMAP), or give a folder with cameras: "
            + _LOOKED_FOR,
            path,
        )
    if layout == "middlebury":
        scene = load_middlebury_scene(path, num_neighbors=k)
    elif layout == "idr":
        scene = load_idr_scene(path, num_neighbors=k)
    elif layout == "llff":
        scene = load_llff_scene(path, num_neighbors=k)
    elif layout == "colmap":
        target = path.parent if path.is_file() else path
        scene = load_colmap_scene(target, image_dir=image_dir, num_neighbors=k)
    elif layout == "dtu":
        scene = load_dtu_scene(path, scan=scan, **cam_args)
    elif layout == "blendedmvs":
        scene = load_blended_scene(path, **cam_args)
    elif layout == "tnt":
        scene = load_tnt_scene(path.parent if path.is_file() else path, short_range=short_range, **cam_args)
    else:
        root = path.parent if path.is_file() else path
        cam_dir = mvsnet_cam_dir(root)
        scene = load_mvsnet_scene(root, cam_dir=cam_dir.name if cam_dir else None, **cam_args)
    if depth_range is not None:
        for v in scene.views:
            v.depth_min, v.depth_max = lo, hi
    scene.source_format = layout
    return scene.validate(require_depth_range=False)
