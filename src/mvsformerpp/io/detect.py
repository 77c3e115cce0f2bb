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

Each is a :class:`Layout` record of :data:`TABLE`: its name, its words in the "looked for" message, the
test that recognises it and the reader that loads it. Adding a format is its reader module plus one record.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mvsformerpp.errors import InputError
from mvsformerpp.io.benchmarks import (
    blended_scene_dir,
    is_dtu_root,
    load_blended_scene,
    load_dtu_scene,
    load_tnt_scene,
)
from mvsformerpp.io.colmap import MODEL_SUBDIRS, find_colmap_model, load_colmap_scene
from mvsformerpp.io.colmap_model import model_extension
from mvsformerpp.io.idr import is_idr_scene, load_idr_scene
from mvsformerpp.io.images import list_images
from mvsformerpp.io.llff import is_llff_scene, load_llff_scene
from mvsformerpp.io.middlebury import find_par_file, load_middlebury_scene
from mvsformerpp.io.mvsnet import DEFAULT_NUM_DEPTH, DepthFormat, cam_files, load_mvsnet_scene
from mvsformerpp.io.scene import Scene

_MODEL_FILES = {f"{n}{e}" for n in ("cameras", "images", "points3D") for e in (".bin", ".txt")}


def mvsnet_cam_dir(path: Path) -> Path | None:
    for name in ("cams", "cams_1"):
        if (path / name).is_dir() and cam_files(path / name):
            return path / name
    return None


def _refuse_incomplete(path: Path) -> None:
    """Name what is missing from a folder that is almost a COLMAP model or an MVSNet scene."""

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


def _has_cams(path: Path) -> bool:
    return path.is_dir() and (path / "images").is_dir() and mvsnet_cam_dir(path) is not None


def _is_mvsnet(path: Path) -> bool:
    return _has_cams(path) and not (path.parent / "short_range_cameras").is_dir()


def _is_tnt(path: Path) -> bool:
    return _has_cams(path) and (path.parent / "short_range_cameras").is_dir()


def _is_colmap(path: Path) -> bool:
    if path.is_file():
        return path.name in _MODEL_FILES and bool(model_extension(path.parent))
    try:
        find_colmap_model(path)
    except InputError:
        return False
    return True


def _is_middlebury(path: Path) -> bool:
    return path.name.endswith("_par.txt") if path.is_file() else find_par_file(path) is not None


def _is_photo_folder(path: Path) -> bool:
    """Photos without cameras, unless the folder is an incomplete scene (refused, naming what is missing)."""
    if path.is_file():
        return False
    _refuse_incomplete(path)
    return bool(list_images(path) or list_images(path / "images"))


@dataclass(frozen=True)
class LoadOptions:
    """How a scene is read (see :func:`load_scene`); each layout uses the options that apply to it."""

    num_neighbors: int = 10
    depth_format: DepthFormat = "auto"
    num_depth: int = DEFAULT_NUM_DEPTH
    interval_scale: float = 1.0
    scan: str | int | None = None
    short_range: bool = False
    image_dir: str | Path | None = None

    def cams(self) -> dict:
        """The options of MVSNet cam files (:mod:`mvsformerpp.io.mvsnet`)."""
        return dict(depth_format=self.depth_format, num_depth=self.num_depth, interval_scale=self.interval_scale,
                    num_neighbors=self.num_neighbors)


def _folder(path: Path) -> Path:
    return path.parent if path.is_file() else path


def _load_mvsnet(path: Path, o: LoadOptions) -> Scene:
    root = _folder(path)
    cam_dir = mvsnet_cam_dir(root)
    return load_mvsnet_scene(root, cam_dir=cam_dir.name if cam_dir else None, **o.cams())


def _refuse_photos(path: Path, o: LoadOptions) -> Scene:
    raise InputError("this folder holds photos but no cameras; multi-view stereo needs calibrated cameras. Run "
                     "structure from motion first (the reconstruct pipeline does it with COLMAP), or give a folder "
                     f"with cameras: {looked_for()}", path)


@dataclass(frozen=True)
class Layout:
    """A scene layout: how to recognise it and how to load it."""

    name: str
    looks_like: str
    """What it is, in the words of the "looked for" message (empty: not listed there)."""
    detect: Callable[[Path], bool]
    """Whether the file or folder at a path is this layout (the table's order decides between layouts)."""
    load: Callable[[Path, LoadOptions], Scene]


TABLE: tuple[Layout, ...] = (
    Layout("mvsnet", "an MVSNet folder (images/ + cams/NNNNNNNN_cam.txt [+ pair.txt])", _is_mvsnet, _load_mvsnet),
    Layout("tnt", "a Tanks-and-Temples scene (the same + short_range_cameras/ beside it)", _is_tnt,
           lambda p, o: load_tnt_scene(_folder(p), short_range=o.short_range, **o.cams())),
    Layout("dtu", "a DTU training root (Cameras/ + Rectified/)", lambda p: p.is_dir() and is_dtu_root(p),
           lambda p, o: load_dtu_scene(p, scan=o.scan, **o.cams())),
    Layout("blendedmvs", "a BlendedMVS scene (blended_images/ + cams/)",
           lambda p: p.is_dir() and blended_scene_dir(p) is not None,
           lambda p, o: load_blended_scene(p, **o.cams())),
    Layout("colmap", "a COLMAP project (sparse/0, sparse/ or cameras/images/points3D .bin/.txt, + images/)",
           _is_colmap, lambda p, o: load_colmap_scene(_folder(p), image_dir=o.image_dir,
                                                      num_neighbors=o.num_neighbors)),
    Layout("middlebury", "a Middlebury *_par.txt file or a folder holding one", _is_middlebury,
           lambda p, o: load_middlebury_scene(p, num_neighbors=o.num_neighbors)),
    Layout("idr", "an IDR/NeuS scene (cameras_sphere.npz + image/)", is_idr_scene,
           lambda p, o: load_idr_scene(p, num_neighbors=o.num_neighbors)),
    Layout("llff", "an LLFF capture (poses_bounds.npy + images/)", is_llff_scene,
           lambda p, o: load_llff_scene(p, num_neighbors=o.num_neighbors)),
    Layout("images", "", _is_photo_folder, _refuse_photos),
)
"""Every layout, in the order :func:`detect_layout` tries them (the first whose test passes wins; the
tests are written not to overlap) and the "looked for" message lists them."""

LAYOUTS: dict[str, Layout] = {layout.name: layout for layout in TABLE}


def looked_for() -> str:
    """The layouts a scene may have, in words."""
    return ", ".join(layout.looks_like for layout in TABLE if layout.looks_like)


def detect_layout(path: str | Path) -> str:
    """The layout name of the scene at ``path`` (see the module docstring); InputError when none fits."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file or folder", path)
    if path.is_file() and path.name == "pair.txt":
        return detect_layout(path.parent)
    for layout in TABLE:
        if layout.detect(path):
            return layout.name
    if path.is_file():
        raise InputError(f"cannot tell the scene layout from this file; give a folder or file holding {looked_for()}",
                         path)
    raise InputError(f"no scene found here; looked for {looked_for()}", path)


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
    options = LoadOptions(num_neighbors=k, depth_format=depth_format, num_depth=num_depth,
                          interval_scale=interval_scale, scan=scan, short_range=short_range, image_dir=image_dir)
    scene = LAYOUTS[layout].load(path, options)
    if depth_range is not None:
        for v in scene.views:
            v.depth_min, v.depth_max = lo, hi
    scene.source_format = layout
    return scene.validate(require_depth_range=False)
