"""Stage 1 of ``reconstruct``: the input as a :class:`~mvsformerpp.io.scene.Scene`, checked and ready.

A plain photo folder first goes through structure from motion (:mod:`.sfm`, kept in ``OUT/sfm``); a
COLMAP project with distorted cameras is undistorted into ``OUT/undistorted``; then the user's overrides
(depth range, number of images) apply and every view is checked (neighbours, depth range, photo sizes).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.io import detect
from mvsformerpp.io.colmap import find_colmap_model, read_model, sparse_point_depths, undistort_colmap
from mvsformerpp.io.images import image_size, list_images
from mvsformerpp.io.masks import load_masks
from mvsformerpp.io.output_folder import scene_fingerprint
from mvsformerpp.io.scene import Scene
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.pipelines.run import Run
from mvsformerpp.pipelines.sfm import SfMConfig, run_sfm

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SceneInput:
    """What stage 1 makes: the input as read, and the scene to reconstruct."""

    full: Scene
    """The input as read (before ``--max-images`` and the depth-range overrides)."""
    scene: Scene
    """The views to reconstruct, overrides applied and checked."""
    fingerprint: str
    """Identity of the input scene (cameras and image sizes), stored in config.json."""
    seconds: float
    """Seconds since the run started."""
    sfm_reused: bool | None
    """Structure from motion was done by an earlier run (None: it did not run for this input)."""


def read_input(run: Run, _: None = None) -> SceneInput:
    """Stage 1: the input as a checked scene (structure from motion or undistortion first, where needed),
    refused when the output folder holds another scene's outputs; bad masks fail now, not after the depth
    maps."""
    config = run.config
    full = load_input(run.input_path, run.folder.root, quiet=run.quiet, depth_range=config.depth_range,
                      depth_format=config.depth_format, sfm=config.sfm)
    fingerprint = scene_fingerprint(full)
    run.folder.check_scene(fingerprint)
    scene = prepare_scene(full, config)
    if config.mask_dir is not None:

        load_masks(config.mask_dir, [v.name for v in scene.views], [(v.height, v.width) for v in scene.views])
    report = run.folder.root / "sfm" / "report.json"  # written only when SfM runs: older than this run means reused
    reused = report.stat().st_mtime < run.started if report.is_file() else None
    return SceneInput(full, scene, fingerprint, time.perf_counter() - run.t0, reused)


def load_input(path: str | Path, out: Path, quiet: bool = False,
               depth_range: tuple[float, float] | None = None, depth_format: str = "auto",
               sfm: SfMConfig | None = None) -> Scene:
    """Load INPUT as a Scene, running SfM (photos) or undistortion (distorted COLMAP) into ``out``.

    ``depth_range`` replaces every view's range (the input's depth lines are then not read at all);
    ``depth_format`` says how two-number MVSNet depth lines are read; ``sfm`` sets up structure from motion.
    """

    path = Path(path)
    if not path.exists():
        raise InputError("no such file or folder", path)
    if (path / "DONE").is_file() and (path / "dense" / "sparse").is_dir():
        log.info("%s is the structure-from-motion folder of a reconstruction: using its dense/ project", path)
        path = path / "dense"
    layout = detect.detect_layout(path)
    if layout == "images":

        photos = path if list_images(path) or not (path / "images").is_dir() else path / "images"
        dense = run_sfm(photos, out / "sfm", quiet=quiet, config=sfm)
        return detect.load_scene(dense, depth_range=depth_range)
    if layout == "colmap" and _colmap_is_distorted(path):

        target = out / "undistorted"
        if not (target / "DONE").is_file():
            log.info("undistorting the COLMAP project into %s", target)
            _check_photo_sizes(path)
            try:
                undistort_colmap(path, target)
            except MVSFormerError:
                raise
            except Exception as e:  # pycolmap reports bad input as RuntimeError/ValueError
                raise InputError(f"COLMAP could not undistort this project ({_first_line(e)})", path) from e
            (target / "DONE").write_text("undistorted\n")
        return detect.load_scene(target, depth_range=depth_range)
    return detect.load_scene(path, depth_range=depth_range, depth_format=depth_format)


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return (text.splitlines()[-1] if text else type(e).__name__)[:300]


def _check_photo_sizes(project: Path) -> None:
    """Every photo of a distorted COLMAP model has its camera's size (undistortion needs the originals)."""

    model_dir, image_dir = find_colmap_model(project)
    if image_dir is None:
        return
    model = read_model(model_dir)
    for im in model.images.values():
        cam, path = model.cameras[im.camera_id], image_dir / im.name
        if path.is_file() and image_size(path) != (cam.width, cam.height):
            w, h = image_size(path)
            raise InputError(f"photo is {w}x{h} but its camera in {model_dir} is {cam.width}x{cam.height}: the model "
                             "and the photos do not belong together (undistorted photos go with the undistorted "
                             "model, e.g. dense/images with dense/sparse)", path)


def _colmap_is_distorted(project: Path) -> bool:
    model = read_model(find_colmap_model(project)[0])
    used = {im.camera_id for im in model.images.values()}
    return any(not cam.is_pinhole for cam in model.cameras.values() if cam.id in used)


def prepare_scene(scene: Scene, config: ReconstructConfig) -> Scene:
    """Apply the user's overrides and check that every view can be reconstructed."""
    where = scene.root
    views = list(scene.views)
    if config.max_images is not None:
        keep = connected_subset(scene, config.max_images)
        new_index = {old: new for new, old in enumerate(keep)}
        views = [dataclasses.replace(views[i], neighbors=[new_index[j] for j in views[i].neighbors if j in new_index])
                 for i in keep]
    if len(views) < 2:
        raise InputError(f"the scene has {len(views)} view(s); multi-view stereo needs at least 2", where)
    if config.depth_range is not None:
        lo, hi = config.depth_range
        views = [dataclasses.replace(v, depth_min=float(lo), depth_max=float(hi)) for v in views]
    elif config.interval_scale != 1.0:
        views = [v if v.depth_min is None or v.depth_max is None else dataclasses.replace(
            v, depth_max=v.depth_min + (v.depth_max - v.depth_min) * config.interval_scale) for v in views]
    lonely = [v.name for v in views if not v.neighbors]
    if lonely:
        raise InputError(
            f"view(s) {', '.join(lonely[:5])}{' ...' if len(lonely) > 5 else ''} have no neighbour views "
            "(no overlapping view in pair.txt / the sparse model): add overlapping photos or fix pair.txt", where)
    out = Scene(views=views, root=scene.root, source_format=scene.source_format)
    out.validate(require_depth_range=True)
    _check_images(out)
    return out


def connected_subset(scene: Scene, n: int) -> list[int]:
    """Up to ``n`` view indices that overlap: view 0, then breadth-first over best neighbours; sorted."""
    chosen: list[int] = []
    queue = [0]
    while queue and len(chosen) < n:
        i = queue.pop(0)
        if i in chosen:
            continue
        chosen.append(i)
        queue.extend(j for j in scene.views[i].neighbors if j not in chosen)
    for i in range(len(scene)):  # disconnected scenes: fill up in order
        if len(chosen) >= n:
            break
        if i not in chosen:
            chosen.append(i)
    return sorted(chosen)


def _check_images(scene: Scene) -> None:
    """Every photo exists, is readable and has the size its camera says (header read only)."""

    for v in scene.views:
        if not v.image_path.is_file():
            raise InputError(f"image of view {v.name} is missing", v.image_path)
        w, h = image_size(v.image_path)
        if (w, h) != (v.width, v.height):
            raise InputError(
                f"image is {w}x{h} but its camera is for {v.width}x{v.height}: use the photos the cameras "
                "were calibrated for", v.image_path)


def working_scene(scene: Scene, plans) -> Scene:
    """The scene at the working resolution: each view's size and intrinsics scaled as its plan resizes it."""
    views = [dataclasses.replace(v, width=p.resized_width, height=p.resized_height, K=p.scale_intrinsics(v.K))
             for v, p in zip(scene.views, plans)]
    return Scene(views=views, root=scene.root, source_format=scene.source_format)


def range_coverage(lo: float, hi: float, own_min: float, own_max: float) -> float:
    """Share of a view's own depth range [own_min, own_max] that [lo, hi] covers (0..1)."""
    return max(0.0, min(hi, own_max) - max(lo, own_min)) / (own_max - own_min)


def warn_if_range_misses_scene(input_path: str | Path, out: Path, config: ReconstructConfig) -> None:
    """Warn when ``--depth-range`` leaves out most of the scene for most views.

    For a COLMAP input: most of the sparse points a view sees lie outside the range; otherwise the
    range covers less than half of the view's own depth range (its cam file's depth line). Almost
    always a unit mix-up (millimetres vs metres), which gives empty depth maps.
    """
    try:
        own = load_input(input_path, out, quiet=True, depth_format=config.depth_format)
    except MVSFormerError:
        return  # the input has no usable ranges of its own: nothing to compare with
    lo, hi = config.depth_range
    if own.source_format == "colmap" and own.root is not None:  # the sparse points each view sees

        z = {k: d for k, d in sparse_point_depths(own.root).items() if len(d)}
        missed = [k for k, d in z.items() if np.mean((d >= lo) & (d <= hi)) < 0.5]
        if z and len(missed) > len(z) / 2:
            d = z[missed[0]]
            log.warning("--depth-range %g %g leaves out most of the sparse points seen by %d of %d views (e.g. %s "
                        "sees them at %.4g .. %.4g); check the units, or leave --depth-range out",
                        lo, hi, len(missed), len(z), missed[0], float(d.min()), float(d.max()))
        return
    ranged = [v for v in own.views if v.depth_min is not None and v.depth_max is not None]
    missed = [v for v in ranged if range_coverage(lo, hi, v.depth_min, v.depth_max) < 0.5]
    if ranged and len(missed) > len(ranged) / 2:
        v = missed[0]
        log.warning("--depth-range %g %g covers less than half of the depth range the input gives %d of %d views "
                    "(e.g. %s: %.4g .. %.4g from its depth line); check the units, or leave --depth-range out",
                    lo, hi, len(missed), len(ranged), v.name, v.depth_min, v.depth_max)
