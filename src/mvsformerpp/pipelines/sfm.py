"""Structure-from-motion for a plain folder of photos, with pycolmap on the CPU.

Stages (each skipped when its output already exists, so an interrupted or repeated run does not
redo finished work; hloc-style ``f(..., out_dir) -> Path``):

1. SIFT features of every photo (one camera per photo, or one for all) -> ``OUT/sfm/database.db``
2. exhaustive or sequential matching + geometric verification (same database)
3. incremental mapping; the largest model  -> ``OUT/sfm/sparse/``
4. undistortion to pinhole cameras         -> ``OUT/sfm/dense/{images,sparse}`` (a COLMAP project)

The result, ``OUT/sfm/dense``, is an undistorted COLMAP project that the COLMAP reader loads like any
other. ``OUT/sfm/DONE`` marks a completed run, ``OUT/sfm/options.json`` its settings (other settings start
over), ``OUT/sfm/report.json`` its outcome. pycolmap's failures become one :class:`InputError` naming the
stage and what to try.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.io.colmap_model import CAMERA_MODELS, read_model
from mvsformerpp.io.colmap_stats import model_statistics
from mvsformerpp.io.images import IMAGE_SUFFIXES, list_images
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.config_flags import flag_name

log = logging.getLogger(__name__)



def import_pycolmap():
    """Import pycolmap or raise :class:`MissingDependencyError` naming the ``colmap`` extra."""
    try:
        import pycolmap
    except ImportError as e:
        raise MissingDependencyError("pycolmap", "colmap", "Structure-from-motion on a folder of photos") from e
    return pycolmap


def write_sfm_report(model_dir: Path, photos: list[str], path: Path, seconds: float | None = None) -> dict:
    """Write the outcome of SfM (registered and dropped photos, points, error, intrinsics and, given, the
    seconds it took) as JSON."""

    stats = model_statistics(read_model(model_dir), photos)
    if seconds is not None:
        stats["seconds"] = round(float(seconds), 3)
    atomic_write_text(path, json.dumps(stats, indent=2) + "\n")
    return stats


def _bar(iterable=None, **kw):
    """A tqdm progress bar. tqdm is imported here, not with the module: every command builds its flags from
    :class:`SfMConfig`, and tqdm's import took a fifth of ``mvsformerpp --help`` (0.09 of 0.53 s)."""
    from tqdm import tqdm

    return tqdm(iterable, **kw)


def _stage(progress, name: str) -> None:
    if progress is not None:
        progress.set_description(f"SfM: {name}")


SFM = "structure from motion (a folder of photos)"


@dataclass(frozen=True)
class SfMConfig:
    """Structure-from-motion settings for a folder of photos (saved to ``OUT/sfm/options.json``)."""

    camera_model: str = field(default="SIMPLE_RADIAL", metadata={"group": SFM, "metavar": "MODEL"})
    """COLMAP camera model to estimate (e.g. PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)."""
    single_camera: bool = field(default=False, metadata={"group": SFM})
    """All photos come from one camera with one lens and zoom (which steadies the intrinsics)."""
    matcher: Literal["exhaustive", "sequential"] = field(default="exhaustive", metadata={"group": SFM})
    """exhaustive: every pair of photos; sequential: each photo with its neighbours in name order (video
    frames)."""
    max_image_size: int = field(default=2000, metadata={"flag": "--sfm-max-size", "group": SFM, "metavar": "PX"})
    """Longest photo side used for SIFT features (COLMAP's own default is 3200)."""
    overlap: int = field(default=10, metadata={"flag": None})
    """sequential: how many following photos each one is matched with."""

    def __post_init__(self) -> None:
        if self.camera_model not in CAMERA_MODELS:
            raise InputError(f"{flag_name(SfMConfig, 'camera_model')} {self.camera_model!r} is not a COLMAP camera "
                             "model; choose one of "
                             f"{', '.join(CAMERA_MODELS)}")
        if self.max_image_size < 64:
            raise InputError(f"{flag_name(SfMConfig, 'max_image_size')} must be at least 64 pixels, "
                             f"got {self.max_image_size}")
        if self.matcher not in ("exhaustive", "sequential"):
            raise InputError(f"{flag_name(SfMConfig, 'matcher')} must be exhaustive or sequential, "
                             f"got {self.matcher!r}")


@contextlib.contextmanager
def _explained(stage: str, hint: str, where: Path):
    """Turn pycolmap's exceptions in ``stage`` into one :class:`InputError` that says what to try."""
    try:
        yield
    except (RuntimeError, ValueError) as e:
        first = (str(e).strip().splitlines() or [type(e).__name__])[-1][:300]
        raise InputError(f"structure-from-motion failed while {stage} ({first}); {hint}", where) from e


MATCH_CALLS = 50
"""Exhaustive matching runs in about this many calls (each a group of pairs), for its progress bar."""


def _match_all_pairs(pycolmap, database: Path, photos: list[str], pairs_file: Path, quiet: bool) -> None:
    """Exhaustive matching (every pair of photos, geometric verification) in groups of pairs, with progress."""

    if any(any(c.isspace() for c in name) for name in photos):  # a pairs file splits names at whitespace
        if not quiet:
            print(f"SfM: matching {len(photos)} photos (exhaustive)", flush=True)
        pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
        return
    pairs = [(a, b) for i, a in enumerate(photos) for b in photos[i + 1:]]
    size = max(1, -(-len(pairs) // MATCH_CALLS))
    options = pycolmap.ImportedPairingOptions()
    options.match_list_path = str(pairs_file)
    with _bar(total=len(pairs), desc="SfM: matching", unit="pair", disable=quiet) as bar:
        for k in range(0, len(pairs), size):
            group = pairs[k:k + size]
            pairs_file.write_text("".join(f"{a} {b}\n" for a, b in group))
            pycolmap.match_image_pairs(database, pairing_options=options, device=pycolmap.Device.cpu)
            bar.update(len(group))
    pairs_file.unlink(missing_ok=True)


def run_sfm(image_dir: str | Path, sfm_dir: str | Path, quiet: bool = False,
            config: SfMConfig | None = None) -> Path:
    """Calibrate the photos in ``image_dir``; return the undistorted COLMAP project ``sfm_dir/dense``.

    A finished run with the same settings is reused. Raises :class:`InputError` when fewer than two
    photos register into one model or pycolmap fails (with what to try).
    """
    config = config or SfMConfig()
    image_dir, sfm_dir = Path(image_dir), Path(sfm_dir)
    dense, done = sfm_dir / "dense", sfm_dir / "DONE"
    options = json.dumps(dataclasses.asdict(config), sort_keys=True)
    same = _same_settings(sfm_dir, options, config)
    if done.is_file() and (dense / "sparse").is_dir() and same:
        log.info("SfM already done in %s; reusing it", sfm_dir)
        return dense
    t0 = time.perf_counter()
    pycolmap = import_pycolmap()
    photos = [p.name for p in list_images(image_dir)]
    if len(photos) < 2:
        raise InputError(
            f"found {len(photos)} photo(s); structure-from-motion needs at least 2 overlapping photos "
            f"({', '.join(IMAGE_SUFFIXES)})",
            image_dir,
        )
    sfm_dir.mkdir(parents=True, exist_ok=True)
    if not same:  # other settings: start over
        for name in ("features.done", "DONE", "database.db"):
            with contextlib.suppress(FileNotFoundError):
                (sfm_dir / name).unlink()
        (sfm_dir / "options.json").write_text(options)
    # COLMAP logs every step at INFO level; keep warnings and errors only (all of it when verbose).
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else (2 if quiet else 1)
    if not (sfm_dir / "features.done").is_file():
        extract_and_match(pycolmap, image_dir, photos, sfm_dir, config, quiet)
        (sfm_dir / "features.done").touch()
    best_dir, best = map_photos(pycolmap, image_dir, photos, sfm_dir, quiet)
    stats = write_sfm_report(best_dir, photos, sfm_dir / "report.json", seconds=time.perf_counter() - t0)
    log.info("SfM registered %d of %d photos", best.num_reg_images(), len(photos))
    if not quiet and stats["dropped"]:
        print(f"SfM: {len(stats['dropped'])} of {len(photos)} photos did not register: "
              f"{', '.join(stats['dropped'][:8])}{' ...' if len(stats['dropped']) > 8 else ''}", flush=True)
    if dense.exists():
        shutil.rmtree(dense)
    with _explained("undistorting", "check the disk space and that the photos are still there", image_dir):
        pycolmap.undistort_images(dense, best_dir, image_dir)
    write_sfm_report(best_dir, photos, sfm_dir / "report.json", seconds=time.perf_counter() - t0)  # undistortion too
    done.write_text(f"registered {best.num_reg_images()} of {len(photos)} photos\n")
    return dense


def _same_settings(sfm_dir: Path, options: str, config: SfMConfig) -> bool:
    """Whether the run in ``sfm_dir`` (if any) was made with these settings (``options``: their JSON)."""
    options_file = sfm_dir / "options.json"
    if not options_file.is_file() and (sfm_dir / "DONE").is_file():
        return config == SfMConfig()  # a run from before options were recorded used the defaults
    return options_file.is_file() and options_file.read_text() == options


def extract_and_match(pycolmap, image_dir: Path, photos: list[str], sfm_dir: Path, config: SfMConfig,
                      quiet: bool) -> Path:
    """Stages 1 and 2: SIFT features of every photo and their verified matches, into ``sfm_dir/database.db``."""
    database = sfm_dir / "database.db"
    # A database left by an interrupted extraction may be incomplete: start it afresh.
    with contextlib.suppress(FileNotFoundError):
        database.unlink()
    opts = pycolmap.FeatureExtractionOptions()
    opts.max_image_size = config.max_image_size
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = config.camera_model
    mode = pycolmap.CameraMode.SINGLE if config.single_camera else pycolmap.CameraMode.PER_IMAGE
    with _explained("extracting features", "check that the photos are readable images", image_dir):
        for k, name in enumerate(_bar(photos, desc="SfM: features", unit="photo", disable=quiet)):
            if config.single_camera and k > 0:
                reader.existing_camera_id = 1  # the camera the first photo created
            pycolmap.extract_features(database, image_dir, image_names=[name], camera_mode=mode,
                                      reader_options=reader, extraction_options=opts, device=pycolmap.Device.cpu)
    with _explained("matching", "try --matcher exhaustive, or photos with more overlap", image_dir):
        if config.matcher == "sequential":
            if not quiet:
                print(f"SfM: matching {len(photos)} photos (sequential)", flush=True)
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = config.overlap
            pycolmap.match_sequential(database, pairing_options=pairing, device=pycolmap.Device.cpu)
        else:
            _match_all_pairs(pycolmap, database, photos, sfm_dir / "pairs.txt", quiet)
    return database


def map_photos(pycolmap, image_dir: Path, photos: list[str], sfm_dir: Path, quiet: bool):
    """Stage 3: incremental mapping; the model with the most registered photos, written to ``sfm_dir/model``.
    Returns (that folder, the model)."""
    sparse = sfm_dir / "sparse"
    if sparse.exists():
        shutil.rmtree(sparse)  # an incomplete mapping from an interrupted run
    sparse.mkdir()
    with (_bar(total=len(photos), desc="SfM: registered", unit="photo", disable=quiet) as bar,
          _explained("mapping", "take more overlapping, textured photos, or try --single-camera", image_dir)):
        models = pycolmap.incremental_mapping(sfm_dir / "database.db", image_dir, sparse,
                                              next_image_callback=lambda: bar.update(1))
        if models:  # the callback counts the images added after the first pair: show the count of the model
            bar.n = max(m.num_reg_images() for m in models.values())
            bar.refresh()
    if not models:
        raise InputError(
            "structure-from-motion found no camera poses: the photos do not overlap enough or have too "
            "little texture; take more overlapping photos",
            image_dir,
        )
    best = models[max(models, key=lambda k: models[k].num_reg_images())]
    if best.num_reg_images() < 2:
        raise InputError("structure-from-motion registered fewer than 2 photos; add overlapping photos", image_dir)
    best_dir = sfm_dir / "model"
    if best_dir.exists():
        shutil.rmtree(best_dir)
    best_dir.mkdir()
    best.write(best_dir)
    return best_dir, best
