"""Structure-from-motion for a plain folder of photos, with pycolmap on the CPU.

Stages (each skipped when its output already exists, so an interrupted or repeated run does not
redo finished work; hloc-style ``f(..., out_dir) -> Path``):

1. SIFT features of every photo            -> ``OUT/sfm/database.db``
2. exhaustive matching + geometric verification (same database)
3. incremental mapping; the largest model  -> ``OUT/sfm/sparse/``
4. undistortion to pinhole cameras         -> ``OUT/sfm/dense/{images,sparse}`` (a COLMAP project)

The result, ``OUT/sfm/dense``, is an undistorted COLMAP project that the COLMAP reader loads like any
other. ``OUT/sfm/DONE`` marks a completed run.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
from pathlib import Path

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.io.images import IMAGE_SUFFIXES, list_images

log = logging.getLogger(__name__)


def import_pycolmap():
    """Import pycolmap or raise :class:`MissingDependencyError` naming the ``colmap`` extra."""
    try:
        import pycolmap
    except ImportError as e:
        raise MissingDependencyError("pycolmap", "colmap", "Structure-from-motion on a folder of photos") from e
    return pycolmap


def _stage(progress, name: str) -> None:
    if progress is not None:
        progress.set_description(f"SfM: {name}")


def run_sfm(image_dir: str | Path, sfm_dir: str | Path, quiet: bool = False, max_image_size: int = 2000) -> Path:
    """Calibrate the photos in ``image_dir``; return the undistorted COLMAP project ``sfm_dir/dense``.

    ``max_image_size`` caps the longest side used for SIFT (COLMAP's own default is 3200).
    Raises :class:`InputError` when fewer than two photos register into one model.
    """
    image_dir, sfm_dir = Path(image_dir), Path(sfm_dir)
    dense = sfm_dir / "dense"
    done = sfm_dir / "DONE"
    if done.is_file() and (dense / "sparse").is_dir():
        log.info("SfM already done in %s; reusing it", sfm_dir)
        return dense
    pycolmap = import_pycolmap()
    photos = [p.name for p in list_images(image_dir)]
    if len(photos) < 2:
        raise InputError(
            f"found {len(photos)} photo(s); structure-from-motion needs at least 2 overlapping photos "
            f"({', '.join(IMAGE_SUFFIXES)})",
            image_dir,
        )
    sfm_dir.mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm

    # COLMAP logs every step at INFO level; keep warnings and errors only (all of it when verbose).
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else (2 if quiet else 1)

    with tqdm(total=4, desc="SfM", unit="stage", disable=quiet) as progress:
        database = sfm_dir / "database.db"
        features_done = sfm_dir / "features.done"
        if not features_done.is_file():
            # A database left by an interrupted extraction may be incomplete: start it afresh.
            with contextlib.suppress(FileNotFoundError):
                database.unlink()
            _stage(progress, "features")
            opts = pycolmap.FeatureExtractionOptions()
            opts.max_image_size = max_image_size
            pycolmap.extract_features(
                database, image_dir, image_names=photos, camera_mode=pycolmap.CameraMode.AUTO,
                extraction_options=opts, device=pycolmap.Device.cpu,
            )
            _stage(progress, "matching")
            pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
            features_done.touch()
        progress.update(2)

        _stage(progress, "mapping")
        sparse = sfm_dir / "sparse"
        if sparse.exists():
            shutil.rmtree(sparse)  # an incomplete mapping from an interrupted run
        sparse.mkdir()
        models = pycolmap.incremental_mapping(database, image_dir, sparse)
        if not models:
            raise InputError(
                "structure-from-motion found no camera poses: the photos do not overlap enough or have too "
                "little texture; take more overlapping photos",
                image_dir,
            )
        best_id = max(models, key=lambda k: models[k].num_reg_images())
        best = models[best_id]
        if best.num_reg_images() < 2:
            raise InputError("structure-from-motion registered fewer than 2 photos; add overlapping photos", image_dir)
        best_dir = sfm_dir / "model"
        if best_dir.exists():
            shutil.rmtree(best_dir)
        best_dir.mkdir()
        best.write(best_dir)
        log.info("SfM registered %d of %d photos", best.num_reg_images(), len(photos))
        progress.update(1)

        _stage(progress, "undistortion")
        if dense.exists():
            shutil.rmtree(dense)
        pycolmap.undistort_images(dense, best_dir, image_dir)
        progress.update(1)
    done.write_text(f"registered {best.num_reg_images()} of {len(photos)} photos\n")
    return dense
