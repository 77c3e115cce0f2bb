"""``reconstruct``: photos / a COLMAP project / an MVSNet folder / a Middlebury set -> depth maps -> PLY.

Stages (each resumable; see :mod:`mvsformerpp.inference.output_folder` for the output layout):

1. input: auto-detect the layout; a plain photo folder first goes through structure-from-motion
   (:mod:`.sfm`, kept in ``OUT/sfm``); a COLMAP project with distorted cameras is undistorted into
   ``OUT/undistorted``;
2. scene: user overrides (depth range, number of images), validation with clear messages, and the
   MVSNet-layout copy of the cameras in ``OUT`` (``images/``, ``cams/``, ``pair.txt``, ``views.json``);
3. depth: the network view by view at a working resolution (:mod:`mvsformerpp.inference`), with the
   per-image feature cache; views already done with the same settings are skipped;
4. fusion: the chosen filter over ``OUT`` into ``OUT/fused.ply``; then ``summary.json``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from mvsformerpp.errors import FormatError, InputError, MVSFormerError
from mvsformerpp.inference.fingerprint import view_fingerprints, weights_identity
from mvsformerpp.inference.output_folder import OutputFolder, disk_full_guard, scene_fingerprint, settings_hash
from mvsformerpp.inference.resolution import available_memory_bytes, choose_long_side, plan_views
from mvsformerpp.inference.runner import SceneInference
from mvsformerpp.io.scene import Scene
from mvsformerpp.pipelines.sfm import SfMConfig

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReconstructConfig:
    """Everything that decides the result of ``reconstruct``; saved to ``OUT/config.json``."""

    preset: Literal["lite", "paper"] = "lite"
    """Network preset (``mvsformerpp.build_model``): ``lite`` (small, CPU-friendly; the package ships trained
    weights for it) or ``paper`` (the official MVSFormer++ network: pass its checkpoint)."""
    checkpoint: str | None = None
    """Weights file matching the preset; None = the weights shipped with the package for ``lite``
    (:mod:`mvsformerpp.models.shipped`), a random initialisation for presets without shipped weights."""
    device: str = "cpu"
    """torch device string, e.g. ``cpu``, ``cuda``, ``cuda:1``."""
    precision: Literal["fp32", "bf16", "fp16"] = "fp32"
    """Autocast precision of the network (the reference runs bf16 on GPU); cost volumes stay fp32."""
    max_size: int | None = 1536
    """Cap on the longer image side at the working resolution (never upscaled); None = no cap."""
    memory_gb: float | None = None
    """Memory budget of one forward and of fusion (which streams the depth maps through a cache of this
    size); None = half of the device's free memory."""
    num_views: int = field(default=5, metadata={"flag": "--views"})
    """Views per depth map: the reference plus ``num_views - 1`` best neighbours (reference: 5 on DTU)."""
    num_depth: int = 192
    """Depth-plane count of the input range, written to the output cams (the cascade uses only the ends
    of the range)."""
    interval_scale: float = 1.0
    """Widen (or narrow) each view's depth range from its minimum by this factor: the reference's
    ``interval_scale`` for ranges given as MIN INTERVAL (DTU: 1.06, so 425 + 191 x 2.5 x 1.06 mm).
    Not applied to an explicit ``depth_range``."""
    temperatures: tuple[float, ...] = (5.0, 5.0, 5.0, 1.0)
    """Per-stage softmax temperatures at inference (spec section 7)."""
    depth_range: tuple[float, float] | None = None
    """Override of every view's depth range (scene units); None = from the input."""
    depth_format: Literal["auto", "interval", "max"] = "auto"
    """How a two-number MVSNet depth line is read: MIN INTERVAL, MIN MAX, or MAX when larger than MIN (auto)."""
    max_images: int | None = None
    """Use only N overlapping views (view 0 and its nearest neighbours; quick looks, tests); None = all."""
    fusion: Literal["normal", "dynamic", "gipuma", "dtu", "tnt_intermediate", "tnt_advanced", "none"] = "normal"
    """Fusion preset (``mvsformerpp.fusion.PRESETS``; ``dtu``, ``tnt_intermediate`` and ``tnt_advanced`` are
    the reference's settings); ``none`` stops after the depth maps (fuse later with ``fuse``)."""
    fusion_conf: float | None = field(default=None, metadata={"flag": "--conf"})
    """Override of the fusion preset's confidence threshold (``--conf``). None: the threshold calibrated for
    the shipped default weights when they run (:func:`fusion_conf_for`), else the preset's."""
    fusion_resolution: Literal["working", "original"] = "working"
    """Size of the depth maps fusion reads: ``working``, the resolution they were computed at (photos larger
    than it do not multiply the points or the fusion time); ``original``: the maps as written (with
    ``output_resolution`` original, upsampled to each photo's size)."""
    output_resolution: Literal["original", "working"] = "original"
    """``original``: depth and confidence maps at each photo's size (upsampled from the working
    resolution); ``working``: at the working resolution, with ``images/`` resized and ``cams/`` scaled
    to match (smaller files, no upsampling, cheaper previews; fusion reads either)."""
    sfm: SfMConfig = field(default=SfMConfig(),
                           metadata={"flag": "--camera-model/--single-camera/--matcher/--sfm-max-size"})
    """Structure-from-motion settings, used when INPUT is a folder of photos."""
    mask_dir: str | None = None
    """Object masks applied before fusion (:mod:`mvsformerpp.io.masks` layouts); None = no masks."""
    cache_mb: int = 2048
    """Feature-cache budget in MiB; 0 recomputes every image's features for every reference view."""
    seed: int = field(default=0, metadata={"flag": None})
    """Seed of the random initialisation when no checkpoint is given (keeps resumed runs consistent)."""

    def __post_init__(self) -> None:
        if self.num_views < 2:
            raise InputError(f"--views must be at least 2 (the reference and one source view), got {self.num_views}")
        if self.num_depth < 2:
            raise InputError(f"--num-depth must be at least 2, got {self.num_depth}")
        if self.max_size is not None and self.max_size < 64:
            raise InputError(f"--max-size must be at least 64 pixels, got {self.max_size}")
        if self.memory_gb is not None and not (math.isfinite(self.memory_gb) and self.memory_gb > 0):
            raise InputError(f"--memory-gb must be a positive number of GB, got {self.memory_gb}")
        if self.cache_mb < 0:
            raise InputError(f"--cache-mb must be >= 0, got {self.cache_mb}")
        if self.depth_range is not None and not (0 < self.depth_range[0] < self.depth_range[1]
                                                 and math.isfinite(self.depth_range[1])):
            raise InputError(f"--depth-range {self.depth_range[0]:g} {self.depth_range[1]:g} must satisfy "
                             "0 < min < max")
        if self.depth_format not in ("auto", "interval", "max"):
            raise InputError(f"--depth-format must be auto, interval or max, got {self.depth_format!r}")
        if not (math.isfinite(self.interval_scale) and self.interval_scale > 0):
            raise InputError(f"--interval-scale must be a positive number, got {self.interval_scale}")
        if self.fusion_conf is not None and not 0 <= self.fusion_conf < 1:
            raise InputError(f"--conf must be a confidence in [0, 1), got {self.fusion_conf}")
        if len(self.temperatures) != 4:
            raise InputError(f"--temperatures needs one value per stage (4), got {self.temperatures}")
        if not all(math.isfinite(t) and t > 0 for t in self.temperatures):
            raise InputError("--temperatures must be four positive numbers (the official runs use 5 5 5 1), got "
                             + " ".join(f"{t:g}" for t in self.temperatures))

    def result_settings(self) -> dict:
        """The fields that change the depth maps (not device or cache size, which only change speed)."""
        d = dataclasses.asdict(self)
        for k in ("device", "memory_gb", "cache_mb", "fusion", "fusion_conf", "fusion_resolution", "mask_dir",
                  "sfm"):  # (SfM: cameras)
            d.pop(k)
        return d


# ---------------------------------------------------------------------------------------------- input


def load_input(path: str | Path, out: Path, num_neighbors: int = 10, quiet: bool = False,
               depth_range: tuple[float, float] | None = None, depth_format: str = "auto",
               sfm: SfMConfig | None = None) -> Scene:
    """Load INPUT as a Scene, running SfM (photos) or undistortion (distorted COLMAP) into ``out``.

    ``depth_range`` replaces every view's range (the input's depth lines are then not read at all);
    ``depth_format`` says how two-number MVSNet depth lines are read; ``sfm`` sets up structure from motion.
    """
    from mvsformerpp.io import detect

    path = Path(path)
    if not path.exists():
        raise InputError("no such file or folder", path)
    if (path / "DONE").is_file() and (path / "dense" / "sparse").is_dir():
        log.info("%s is the structure-from-motion folder of a reconstruction: using its dense/ project", path)
        path = path / "dense"
    layout = detect.detect_layout(path)
    if layout == "images":
        from mvsformerpp.io.images import list_images
        from mvsformerpp.pipelines.sfm import run_sfm

        photos = path if list_images(path) or not (path / "images").is_dir() else path / "images"
        dense = run_sfm(photos, out / "sfm", quiet=quiet, config=sfm)
        return detect.load_scene(dense, depth_range=depth_range)
    if layout == "colmap" and _colmap_is_distorted(path):
        from mvsformerpp.io.colmap import undistort_colmap

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
    from mvsformerpp.io.colmap import find_colmap_model, read_model
    from mvsformerpp.io.images import image_size

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
    from mvsformerpp.io.colmap import find_colmap_model, read_model

    model = read_model(find_colmap_model(project)[0])
    used = {im.camera_id for im in model.images.values()}
    return any(not cam.is_pinhole for cam in model.cameras.values() if cam.id in used)


def prepare_scene(scene: Scene, config: ReconstructConfig) -> Scene:
    """Apply the user's overrides and check that every view can be reconstructed."""
    where = scene.root
    views = list(scene.views)
    if config.max_images is not None:
        if config.max_images < 2:
            raise InputError(f"--max-images must be at least 2, got {config.max_images}")
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
    if config.depth_range is not None and not 0 < config.depth_range[0] < config.depth_range[1]:
        raise InputError(f"--depth-range {config.depth_range[0]} {config.depth_range[1]} must satisfy 0 < min < max")
    out = Scene(views=views, root=scene.root, source_format=scene.source_format)
    out.validate(require_depth_range=True)
    _check_images(out)
    return out


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
        from mvsformerpp.io.colmap import sparse_point_depths

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
    from mvsformerpp.io.images import image_size

    for v in scene.views:
        if not v.image_path.is_file():
            raise InputError(f"image of view {v.name} is missing", v.image_path)
        w, h = image_size(v.image_path)
        if (w, h) != (v.width, v.height):
            raise InputError(
                f"image is {w}x{h} but its camera is for {v.width}x{v.height}: use the photos the cameras "
                "were calibrated for", v.image_path)


# ---------------------------------------------------------------------------------------------- model


def build_network(config: ReconstructConfig) -> torch.nn.Module:
    """The preset's network on the configured device with its weights: the checkpoint if one is given, else
    the shipped default weights (``lite``), else a seeded random initialisation."""
    import mvsformerpp
    from mvsformerpp.models import shipped

    if config.checkpoint is not None:
        ckpt = Path(config.checkpoint)
        if not ckpt.is_file():
            raise InputError("checkpoint file not found", ckpt)
        _check_stored_preset(ckpt, config.preset)
    torch.manual_seed(config.seed)
    model = mvsformerpp.build_model(config.preset)
    if config.checkpoint is not None:
        try:
            mvsformerpp.load_checkpoint(model, ckpt)
        except MVSFormerError:
            raise
        except (RuntimeError, KeyError, ValueError) as e:
            raise FormatError(
                f"checkpoint does not match the '{config.preset}' preset ({str(e).splitlines()[0][:300]}); "
                "pass the preset it was trained with (--preset)", ckpt) from e
    elif config.preset == shipped.SHIPPED_PRESET:
        shipped.load_shipped(model)
    return model.to(torch.device(config.device)).eval()


def _check_stored_preset(ckpt: Path, preset: str) -> None:
    """A safetensors checkpoint that records its config must be for ``preset``: else say which preset it is for."""
    if ckpt.suffix != ".safetensors":
        return
    from mvsformerpp.models.checkpoint import read_safetensors
    from mvsformerpp.models.config import get_config, presets_for

    _, stored = read_safetensors(ckpt)
    if stored is None:
        return
    fits = presets_for(stored)
    if preset in fits:
        return
    if fits:
        raise InputError(f"checkpoint is for the '{fits[0]}' preset (its stored config), not '{preset}': "
                         f"pass --preset {fits[0]}", ckpt)
    wanted = get_config(preset).to_dict()
    diff = sorted(k for k, v in stored.to_dict().items() if wanted.get(k) != v)
    raise InputError(f"checkpoint's stored config fits no preset (it differs from '{preset}' in "
                     f"{', '.join(diff[:6])}); load it from Python with mvsformerpp.load_model", ckpt)


def describe_weights(config: ReconstructConfig) -> str:
    """One line saying which weights ``build_network(config)`` uses."""
    from mvsformerpp.models import shipped

    if config.checkpoint is not None:
        return f"weights: {config.checkpoint} ('{config.preset}' preset)"
    if config.preset == shipped.SHIPPED_PRESET:
        return "weights: " + shipped.describe_shipped()
    return (f"weights: NONE - the '{config.preset}' preset has no shipped weights, so the network is randomly "
            "initialised and the depth maps are not meaningful; pass --checkpoint (for the paper preset: the "
            "official model_best.pth), or use --preset lite for the shipped default weights")


def weights_name(config: ReconstructConfig) -> str:
    """The weights ``build_network(config)`` runs, in a few words (config.json, the report)."""
    from mvsformerpp.models import shipped

    if config.checkpoint is not None:
        return str(config.checkpoint)
    if config.preset == shipped.SHIPPED_PRESET:
        r = shipped.shipped_record()
        return f"the shipped default weights {r['file']} (sha256 {r['sha256'][:12]})"
    return f"random initialisation (seed {config.seed}): no checkpoint given"


def fusion_conf_for(config: ReconstructConfig) -> float | None:
    """The confidence threshold fusion runs with: ``fusion_conf`` when given; with the shipped weights, the
    threshold calibrated for them and the preset's fusion method; otherwise None (the preset's own)."""
    from mvsformerpp.fusion import PRESETS
    from mvsformerpp.models import shipped

    if config.fusion_conf is not None or config.fusion == "none" or not shipped.runs_shipped(config.preset,
                                                                                             config.checkpoint):
        return config.fusion_conf
    return shipped.calibrated_conf(PRESETS[config.fusion].method)


def describe_fusion(config: ReconstructConfig) -> str | None:
    """One line saying how the depth maps will be fused (None without fusion)."""
    if config.fusion == "none":
        return None
    from mvsformerpp.fusion import PRESETS

    conf = fusion_conf_for(config)
    if config.fusion_conf is not None:
        why = "--conf"
    elif conf is not None:
        why = "calibrated for the default weights; --conf sets another"
    else:
        conf, why = PRESETS[config.fusion].conf_threshold, "the preset's"
    return f"fusion: {config.fusion}, confidence threshold {conf:g} ({why})"


def weights_id(config: ReconstructConfig) -> str:
    """Identity of the weights for the resume check (the shipped file's digest: new weights redo the views)."""
    from mvsformerpp.models import shipped

    if shipped.runs_shipped(config.preset, config.checkpoint):
        return "shipped:" + shipped.shipped_record()["sha256"]
    return f"checkpoint:{config.checkpoint}" if config.checkpoint else f"random:{config.seed}"


# ---------------------------------------------------------------------------------------------- main


def reconstruct(input_path: str | Path, out_dir: str | Path, config: ReconstructConfig = ReconstructConfig(),
                quiet: bool = False, model: torch.nn.Module | None = None) -> dict:
    """Reconstruct INPUT into ``out_dir``; return the summary (also written to ``summary.json``).

    ``model`` replaces the preset's network (already on the device), e.g. for tests or benchmarks.
    Finished views are skipped on a repeated call with the same settings. ``out_dir`` must not be,
    contain or lie inside INPUT, nor hold files of anything but an earlier ``reconstruct``; one run
    at a time holds it (:mod:`mvsformerpp.utils.output_guard`). Under ``torchrun`` the processes share
    the views out (:mod:`mvsformerpp.inference.ranks`), rank 0 holds the folder for them and fuses.
    """
    from mvsformerpp.inference.ranks import ranks_from_env
    from mvsformerpp.utils.output_guard import claim_output_folder

    if not Path(input_path).exists():
        raise InputError("no such file or folder", input_path)
    if config.checkpoint is not None and model is None and not Path(config.checkpoint).is_file():
        raise InputError("checkpoint file not found", config.checkpoint)
    _device(config.device)
    ranks = ranks_from_env(config.device)
    try:
        with claim_output_folder(out_dir, [input_path], "reconstruct"):
            return _reconstruct(input_path, out_dir, config, quiet or not ranks.is_main, model, ranks)
    finally:
        ranks.close()


BYTES_PER_OUTPUT_PIXEL = 11
"""Disk per pixel of a view's outputs: depth and confidence PFM (4 + 4 bytes) and two PNG previews (about 3)."""


def plan_line(scene: Scene, plans, todo: list[int], config: ReconstructConfig) -> str:
    """What the run is about to do, said before the long steps: views, working size, what is left to compute
    and the disk the depth maps will take."""
    working = config.output_resolution == "working"
    pixels = sum((p.resized_width * p.resized_height) if working else (v.width * v.height)
                 for v, p in zip(scene.views, plans))
    size = f"{plans[0].resized_width}x{plans[0].resized_height}"
    left = (f"all {len(todo)} to compute" if len(todo) == len(scene)
            else f"{len(todo)} to compute, {len(scene) - len(todo)} done before")
    disk = pixels * BYTES_PER_OUTPUT_PIXEL
    return (f"plan: {len(scene)} views at {size} (working resolution), {config.num_views} views per depth map; "
            f"{left}; the depth maps take about {_size(disk)} on disk"
            + ("" if config.fusion == "none" else ", plus the fused cloud"))


def _size(nbytes: float) -> str:
    return f"{nbytes / 2**30:.1f} GB" if nbytes >= 2**30 else f"{max(1, round(nbytes / 2**20))} MB"


def config_flag(name: str) -> str:
    """The command-line flag of a :class:`ReconstructConfig` field (its ``flag`` metadata, else ``--name-like-this``;
    fields without a flag are named as fields)."""
    meta = next(f.metadata for f in dataclasses.fields(ReconstructConfig) if f.name == name)
    if "flag" in meta:
        return meta["flag"] or f"{name} (a ReconstructConfig field)"
    return "--" + name.replace("_", "-")


def _reconstruct(input_path, out_dir, config: ReconstructConfig, quiet: bool, model, ranks) -> dict:
    from tqdm import tqdm

    from mvsformerpp.inference.ranks import StoppedByOtherRank

    timings: dict[str, float] = {}
    t0, started = time.perf_counter(), time.time()
    ranks.agree({"INPUT": str(input_path), "-o": str(out_dir),
                 **{config_flag(k): v for k, v in dataclasses.asdict(config).items()}})
    folder = ranks.in_turn(lambda: _open_folder(out_dir, ranks))
    ranks.check_shared_folder(folder.root)
    full = ranks.in_turn(lambda: load_input(input_path, folder.root, quiet=quiet, depth_range=config.depth_range,
                                            depth_format=config.depth_format, sfm=config.sfm))

    def setup():
        fingerprint = scene_fingerprint(full)
        folder.check_scene(fingerprint)
        return fingerprint, prepare_scene(full, config), _device(config.device, ranks)

    fingerprint, scene, device = ranks.step(setup)
    if config.num_views > len(scene):  # more would only repeat source views: slower, not better
        if ranks.is_main and config.num_views != ReconstructConfig.num_views:  # said when asked for, not by default
            log.warning("the scene has %d images: %d views per depth map (--views %d asks for more than there are)",
                        len(scene), len(scene), config.num_views)
        config = dataclasses.replace(config, num_views=len(scene))
    ranks.agree({"the input scene (cameras and images)": fingerprint})
    if config.depth_range is not None and ranks.is_main:
        warn_if_range_misses_scene(input_path, folder.root, config)
    if config.mask_dir is not None:  # bad masks fail now, not after the depth maps
        from mvsformerpp.io.masks import load_masks

        load_masks(config.mask_dir, [v.name for v in scene.views], [(v.height, v.width) for v in scene.views])
    timings["input_s"] = time.perf_counter() - t0
    sfm_report = folder.root / "sfm" / "report.json"
    if sfm_report.is_file():  # written only when SfM runs: older than this run means reused
        timings["sfm_reused"] = sfm_report.stat().st_mtime < started

    sizes = [(v.width, v.height) for v in scene.views]
    budget = config.memory_gb * 2**30 if config.memory_gb else 0.5 * available_memory_bytes(device)
    # Rank 0's choice for all: free memory differs between machines, the working resolution may not.
    long_side = ranks.broadcast(choose_long_side(sizes, config.num_views, config.max_size, budget))
    plans = plan_views(sizes, long_side)
    resolved = {"long_side": long_side, "canvas": [plans[0].canvas_width, plans[0].canvas_height]}
    named = weights_name(config) if model is None else "a network passed to reconstruct()"
    fusion_conf = config.fusion_conf if model is not None else fusion_conf_for(config)
    weights = None
    if model is None:  # a checkpoint file's identity, or the shipped weights' digest (new weights redo the views)
        weights = weights_identity(config.checkpoint) if config.checkpoint else weights_id(config)
    keys = view_fingerprints(scene, config.num_views, {**config.result_settings(), **resolved}, weights)
    # the depth previews grey what fusion's confidence threshold drops
    preview_conf = None if config.fusion == "none" else (
        fusion_conf if fusion_conf is not None else _fusion_config(config.fusion).conf_threshold)

    def write_scene() -> list[int]:
        """Cameras, pairs and image links in the MVSNet layout (fusion reads them from here); the views to do."""
        from mvsformerpp.io.mvsnet import write_mvsnet_scene

        working = config.output_resolution == "working"
        with disk_full_guard(folder.root):
            write_mvsnet_scene(working_scene(scene, plans) if working else scene, folder.root, copy_images=False,
                               num_depth=config.num_depth)
            for i, v in enumerate(scene.views):
                if working:
                    folder.write_working_image(i, v.image_path, plans[i])
                else:
                    folder.link_image(i, v.image_path)
        folder.write_json("views.json", {f"{i:08d}": v.name for i, v in enumerate(scene.views)})
        folder.write_json("config.json", {"config": dataclasses.asdict(config),
                                          "resolved": {**resolved, "fusion_conf": fusion_conf, "weights": named},
                                          "scene_fingerprint": fingerprint, "input": str(Path(input_path).resolve()),
                                          "source_format": full.source_format, "num_views_in_input": len(full)})
        todo = [i for i in range(len(scene)) if not folder.view_done(i, keys[i])]
        folder.redraw_previews([i for i in range(len(scene)) if i not in set(todo)], preview_conf)
        return todo

    todo = ranks.broadcast(ranks.step(write_scene, only_main=True))
    if not quiet and ranks.is_main:
        print(plan_line(scene, plans, todo, config), flush=True)

    t1 = time.perf_counter()
    cache_stats = schedule = None
    if todo:
        def start():
            net = model if model is not None else build_network(config)
            from mvsformerpp.io.images import read_image

            runner = SceneInference(net, scene, plans, lambda i: read_image(scene.views[i].image_path),
                                    num_views=config.num_views, num_depth=config.num_depth,
                                    temperatures=config.temperatures, device=device, precision=config.precision,
                                    cache_bytes=config.cache_mb << 20, output_resolution=config.output_resolution)
            return runner, runner.schedule(todo)

        runner, schedule = ranks.step(start)
        mine = ranks.shard(schedule["order"])
        error = None
        try:
            for i in tqdm(mine, desc="Depth maps", unit="view", disable=quiet):
                stop = ranks.stop_requested(folder.root)
                if stop is not None:
                    raise StoppedByOtherRank(stop)
                res = runner.infer(i)
                folder.write_view(i, res.depth, res.confidence, keys[i], preview_conf)
        except Exception as e:  # (exchanged with the other ranks, then raised again)
            error = e
        ranks.outcome(error)
        cache_stats = runner.cache.stats()
    timings["depth_s"] = time.perf_counter() - t1
    timings["views_computed"] = len(todo)
    timings["views_reused"] = len(scene) - len(todo)
    per_rank = ranks.gather({"views": len(ranks.shard(schedule["order"])) if schedule else 0,
                             "depth_s": round(timings["depth_s"], 3), "feature_cache": cache_stats})

    def finish() -> dict:
        folder.fold_rank_progress()
        t2 = time.perf_counter()
        ply = folder.root / "fused.ply"
        points = None
        if config.fusion != "none":
            fusion_size = long_side if config.fusion_resolution == "working" else None
            fusion_state = settings_hash({"depth": keys, "fusion": config.fusion, "conf": fusion_conf,
                                          **({"max_size": fusion_size} if fusion_size else {}),
                                          **({"masks": str(Path(config.mask_dir).resolve())} if config.mask_dir
                                             else {})})
            timings["fusion_reused"] = folder.fusion_done(fusion_state)
            if not timings["fusion_reused"]:
                with disk_full_guard(ply):
                    _run_fusion(folder.root, ply, config.fusion, quiet, config.memory_gb, fusion_conf,
                                config.mask_dir, fusion_size)
                folder.mark_fusion(fusion_state)
            from mvsformerpp.io.ply import ply_vertex_count

            points = ply_vertex_count(ply)
        timings["fusion_s"] = time.perf_counter() - t2
        timings["total_s"] = time.perf_counter() - t0
        summary = {
            "views": len(scene),
            "points": points,
            "working_resolution": resolved,
            "fusion_conf": fusion_conf,
            "preset": config.preset,
            "checkpoint": config.checkpoint,
            "weights": describe_weights(config) if model is None else "a network given by the caller",
            "timings": {k: round(v, 3) if isinstance(v, float) else v for k, v in timings.items()},
            "feature_cache": _sum_stats([r["feature_cache"] for r in per_rank]),
            "schedule": None if schedule is None else {k: v for k, v in schedule.items() if k != "order"},
            "ranks": per_rank if ranks.distributed else None,
            "outputs": {"ply": str(ply) if points is not None else None,
                        "depth_vis": str(folder.root / "depth_vis"), "report": str(folder.root / "report.html")},
        }
        folder.write_json("summary.json", summary)
        from mvsformerpp.viewer.report import write_report

        with disk_full_guard(folder.root / "report.html"):
            write_report(folder.root)
        return summary

    return ranks.broadcast(ranks.step(finish, only_main=True))


def _open_folder(out_dir, ranks) -> OutputFolder:
    """This rank's view of the output folder. Under torchrun, rank 0 opens it first (before any rank
    writes) and removes the temporaries a killed run left, which a single process does when it claims
    the folder (:func:`~mvsformerpp.utils.output_guard.claim_output_folder`)."""
    folder = OutputFolder(out_dir, rank=ranks.rank)
    if ranks.distributed and ranks.is_main:
        from mvsformerpp.utils.output_guard import remove_temporaries

        remove_temporaries(folder.root)
    return folder


def working_scene(scene: Scene, plans) -> Scene:
    """The scene at the working resolution: each view's size and intrinsics scaled as its plan resizes it."""
    views = [dataclasses.replace(v, width=p.resized_width, height=p.resized_height, K=p.scale_intrinsics(v.K))
             for v, p in zip(scene.views, plans)]
    return Scene(views=views, root=scene.root, source_format=scene.source_format)


def _sum_stats(stats: list[dict | None]) -> dict | None:
    """Feature-cache counters of all ranks added up (None when no rank computed a view)."""
    stats = [s for s in stats if s is not None]
    if not stats:
        return None
    return {k: sum(s[k] for s in stats) for k in stats[0]}


def _device(name: str, ranks=None) -> torch.device:
    """The torch device of ``--device``; ``cuda`` under torchrun is each rank's GPU ``LOCAL_RANK``."""
    from mvsformerpp.utils.device import parse_device

    device = parse_device(name)
    if device.type == "cuda" and device.index is None and ranks is not None and ranks.distributed:
        device = torch.device("cuda", ranks.local_rank)
    return device


def _fusion_config(name: str, conf: float | None = None):
    """The named fusion preset of :mod:`mvsformerpp.fusion`, with ``conf`` as its confidence threshold."""
    from mvsformerpp.fusion import get_config

    return get_config(name) if conf is None else get_config(name, conf_threshold=conf)


def _run_fusion(folder: Path, ply: Path, name: str, quiet: bool, memory_gb: float | None = None,
                conf: float | None = None, mask_dir: str | None = None, max_size: int | None = None) -> None:
    from mvsformerpp.pipelines.fuse import fuse

    fuse(folder, ply, _fusion_config(name, conf), quiet=quiet, memory_gb=memory_gb, mask_dir=mask_dir,
         max_size=max_size)
