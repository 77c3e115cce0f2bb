"""What separates real indoor captures from the synthetic rooms: one degradation at a time, measured.

Synthetic rooms seen by a walking handheld camera (the quality check's indoor-video proxy: training style,
``room`` layout, held-out seeds, 640x480, 5 views) are reconstructed as a user runs ``reconstruct``, once
as rendered and once per condition below, with the weights given (the shipped ones by default). Each
condition changes what a real capture changes and nothing else; the ground truth stays as rendered:

* ``jpeg``: JPEG at quality 60; ``blur``: motion blur along a line of 5-11 px at a random angle;
  ``noise``: shot noise, sigma 0.04 * sqrt(intensity); ``exposure``: a gain of 0.6-1.4 and a gamma of
  0.8-1.25 per view (auto-exposure); ``vignetting``: brightness falling to 60 % in the corners;
  ``distortion``: radial distortion k1 = 0.08 left in the photos (the cams stay pinhole);
  ``phone``: exposure, a shorter blur (3-7 px), noise and JPEG at 70 together (phone video);
* ``range_2x`` / ``range_4x``: the cam files' depth range widened to 0.5x .. 2x (0.25x .. 4x) of the true
  one (a loose range from a sensor or SfM);
* ``painted``: every wall and ceiling painted one colour (large surfaces with nothing to match).

Per condition: the share of valid pixels within 10 % of the true depth, the median AbsRel, the share
within 1 % of the cam files' depth range (the widened one in the range conditions), and the within-10 %
share split into flat pixels (the photo's 9x9 standard deviation under 3/255: nothing to match) and the
rest, with the flat pixels' share.

    PYTHONPATH=src python bench/degradations.py [--scenes 4] [--only jpeg painted ...] [--checkpoint PATH]
                                                [--size 480 640] [--max-size PX] [--json PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import tempfile
import zlib
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

FLAT_STD = 3.0 / 255.0
"""A pixel is flat when its photo's 9x9 standard deviation (grey, 0..1) is below this."""


def _load(path: Path) -> np.ndarray:
    """A photo as float RGB in 0..1 (the package's image reader)."""
    from mvsformerpp.io.images import read_image

    return read_image(path).astype(np.float32) / 255.0


def _save(path: Path, img: np.ndarray, jpeg: int | None = None) -> None:
    """Write ``img`` (0..1) back as PNG; with ``jpeg``, through a JPEG round trip at that quality."""
    pil = Image.fromarray(np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8))
    if jpeg is not None:
        buf = io.BytesIO()
        pil.save(buf, format="JPEG", quality=jpeg)
        buf.seek(0)
        pil = Image.open(buf).convert("RGB")
    pil.save(path)


def motion_blur(img: np.ndarray, length: int, angle: float) -> np.ndarray:
    """Average of ``img`` along a line of ``length`` pixels at ``angle`` (radians) through each pixel."""
    t = np.linspace(-(length - 1) / 2, (length - 1) / 2, length)
    out = np.zeros_like(img)
    for s in t:
        out += ndimage.shift(img, (s * np.sin(angle), s * np.cos(angle), 0), order=1, mode="nearest")
    return out / length


def radial_distortion(img: np.ndarray, K: np.ndarray, k1: float) -> np.ndarray:
    """The photo a lens with radial distortion ``k1`` takes of the pinhole image ``img`` (intrinsics ``K``):
    each distorted pixel looks up the undistorted point x_u with x_d = x_u (1 + k1 |x_u|^2)."""
    h, w = img.shape[:2]
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    xd, yd = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    xu, yu = xd.copy(), yd.copy()
    for _ in range(8):  # fixed point of x_u = x_d / (1 + k1 |x_u|^2)
        f = 1.0 + k1 * (xu * xu + yu * yu)
        xu, yu = xd / f, yd / f
    coords = [yu * K[1, 1] + K[1, 2], xu * K[0, 0] + K[0, 2]]
    return np.stack([ndimage.map_coordinates(img[..., c], coords, order=1, mode="nearest")
                     for c in range(3)], axis=-1)


def _exposure(img, rng):
    return np.clip(img * rng.uniform(0.6, 1.4), 0, 1) ** rng.uniform(0.8, 1.25)


def _noise(img, rng):
    return img + 0.04 * np.sqrt(np.clip(img, 0, 1)) * rng.standard_normal(img.shape).astype(np.float32)


def _blur(img, rng, lo=5, hi=11):
    return motion_blur(img, int(rng.integers(lo, hi + 1)), rng.uniform(0, np.pi))


def _vignetting(img):
    h, w = img.shape[:2]
    v, u = np.mgrid[0:h, 0:w]
    r2 = ((u - (w - 1) / 2) ** 2 + (v - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
    return img * (1.0 - 0.4 * r2)[..., None]


PHOTO_CONDITIONS = {
    "jpeg": lambda img, rng, K: (img, 60),
    "blur": lambda img, rng, K: (_blur(img, rng), None),
    "noise": lambda img, rng, K: (_noise(img, rng), None),
    "exposure": lambda img, rng, K: (_exposure(img, rng), None),
    "vignetting": lambda img, rng, K: (_vignetting(img), None),
    "distortion": lambda img, rng, K: (radial_distortion(img, K, 0.08), None),
    "phone": lambda img, rng, K: (_noise(_blur(_exposure(img, rng), rng, 3, 7), rng), 70),
}
"""Photo degradations: ``(photo 0..1, rng, K) -> (degraded photo, JPEG quality or None)``."""
RANGE_CONDITIONS = {"range_2x": 2.0, "range_4x": 4.0}
"""Depth-range conditions: the cam files' range becomes min / f .. max * f."""
CONDITIONS = ("none", *PHOTO_CONDITIONS, *RANGE_CONDITIONS, "painted")


def flat_mask(img: np.ndarray) -> np.ndarray:
    """Pixels whose 9x9 grey standard deviation is under :data:`FLAT_STD`."""
    grey = img.mean(axis=-1)
    mean = ndimage.uniform_filter(grey, 9)
    return ndimage.uniform_filter(grey * grey, 9) - mean * mean < FLAT_STD**2


def preparer(condition: str, seed: int):
    """The ``prepare`` hook of :func:`model_quality.synthetic_quality` (bench/model_quality.py) for
    ``condition``; it first stores each view's flat pixels (``flat/NNNNNNNN.npy``: flatness is the
    scene's, measured on the photos as rendered)."""
    from mvsformerpp.io.mvsnet import read_cam, write_cam

    def prepare(scene_dir: Path) -> None:
        rng = np.random.default_rng([seed, zlib.crc32(scene_dir.name.encode())])
        (scene_dir / "flat").mkdir(exist_ok=True)
        for cam_path in sorted((scene_dir / "cams").glob("*_cam.txt")):
            stem = cam_path.name.replace("_cam.txt", "")
            img_path = scene_dir / "images" / f"{stem}.png"
            img = _load(img_path)
            np.save(scene_dir / "flat" / f"{stem}.npy", flat_mask(img))
            cam = read_cam(cam_path)
            if condition in RANGE_CONDITIONS:
                f = RANGE_CONDITIONS[condition]
                write_cam(cam_path, dataclasses.replace(cam, depth_min=cam.depth_min / f,
                                                        depth_max=cam.depth_max * f, depth_interval=None,
                                                        num_depth=None))
            elif condition in PHOTO_CONDITIONS:
                img, quality = PHOTO_CONDITIONS[condition](img, rng, cam.K)
                _save(img_path, img, quality)

    return prepare


def flat_split(out: Path, scenes: int, views: int) -> dict:
    """Within 10 % of the depth on flat pixels and on the rest, and the flat pixels' share."""
    from mvsformerpp.io.pfm import read_pfm

    n = {True: 0, False: 0}
    ok = {True: 0, False: 0}
    for k in range(scenes):
        for i in range(views):
            flat = np.load(out / f"scene_{k}" / "flat" / f"{i:08d}.npy")
            gt = read_pfm(out / f"scene_{k}" / "depth_gt" / f"{i:08d}.pfm")
            est = read_pfm(out / f"recon_{k}" / "depth_est" / f"{i:08d}.pfm")
            valid = gt > 0
            close = np.abs(est - gt) < 0.1 * gt
            for is_flat in (True, False):
                sel = valid & (flat == is_flat)
                n[is_flat] += int(sel.sum())
                ok[is_flat] += int((close & sel).sum())
    total = n[True] + n[False]
    return {"flat_share": n[True] / total,
            "flat_within_10pct": ok[True] / n[True] if n[True] else None,
            "other_within_10pct": ok[False] / n[False] if n[False] else None}


def main() -> None:
    from model_quality import HELDOUT_SEED, synthetic_quality  # bench/ is on the path when a bench script runs

    from mvsformerpp.pipelines.reconstruct import ReconstructConfig

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=4)
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--size", type=int, nargs=2, default=(480, 640), metavar=("H", "W"))
    ap.add_argument("--only", nargs="+", choices=CONDITIONS, help="these conditions (default: all)")
    ap.add_argument("--checkpoint", help="weights to measure (default: the shipped ones)")
    ap.add_argument("--max-size", type=int, metavar="PX",
                    help="working size of reconstruct (longer side; default the photos' own): the depth maps are "
                         "compared at the photos' size, as reconstruct writes them")
    ap.add_argument("--json", help="also write the rows here")
    args = ap.parse_args()
    if args.max_size is not None and args.max_size < 64:
        ap.error(f"--max-size must be at least 64 pixels, got {args.max_size}")

    config = ReconstructConfig(preset="lite", checkpoint=args.checkpoint, num_views=args.views, fusion="normal")
    rows = []
    print(f"{'condition':<12} {'within 10 %':>11} {'AbsRel':>7} {'within 1 %':>10} "
          f"{'flat share':>10} {'flat 10 %':>9} {'other 10 %':>10}", flush=True)
    for condition in args.only or CONDITIONS:
        with tempfile.TemporaryDirectory() as tmp:
            q = synthetic_quality(tmp, config, style="train", layout="room", scenes=args.scenes,
                                  seed=HELDOUT_SEED, num_views=args.views, height=args.size[0],
                                  width=args.size[1], plain_walls=1.0 if condition == "painted" else 0.0,
                                  prepare=preparer(condition, HELDOUT_SEED), max_size=args.max_size)
            split = flat_split(Path(tmp), args.scenes, args.views)
        row = {"condition": condition, "within_10pct_depth": q["within_10pct_depth"],
               "median_abs_rel": q["median_abs_rel"], "within_1pct": q["within_1pct"], **split}
        rows.append(row)
        flat = split["flat_within_10pct"]
        print(f"{condition:<12} {100 * row['within_10pct_depth']:10.1f}% {row['median_abs_rel']:7.3f} "
              f"{100 * row['within_1pct']:9.1f}% {100 * split['flat_share']:9.1f}% "
              f"{'-' if flat is None else f'{100 * flat:8.1f}%':>9} {100 * split['other_within_10pct']:9.1f}%",
              flush=True)
    if args.json:
        from mvsformerpp.utils.atomic import atomic_write_text

        record = {"checkpoint": args.checkpoint, "max_size": args.max_size, "rows": rows}
        atomic_write_text(args.json, json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
