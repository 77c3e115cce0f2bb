"""How good a set of weights is, measured through ``reconstruct`` (what users get), on three kinds of data.

- :func:`synthetic_quality`: scenes from :mod:`mvsformerpp.synth` with exact ground truth, on seeds no
  training run uses (training takes seeds ``seed .. seed + scenes``, validation ``seed + 10^6 ..``) and
  on the ``heldout`` style training never sees. Depth: the share of valid pixels within 1 % of the
  view's depth range (the cam file's min..max) and within 10 % of the true depth; cloud: accuracy and
  completeness of the fused cloud against the scene's ground-truth surface, as a percentage of the mean
  ground-truth depth.
- :func:`dtu_pair_quality`: the two real DTU views with ground-truth depth in ``tests/data/dtu_pair``:
  the share of valid ground-truth pixels within 4 mm and 8 mm, and within 10 % of the true depth.
- :func:`calibrate_fusion_conf`: the fusion confidence threshold that suits a set of weights, chosen on
  synthetic scenes of other seeds (:data:`CALIBRATION_SEED`) by the fused cloud's F_beta score
  (precision weighted: :data:`FUSION_BETA`).
- :func:`temple_quality`: the Middlebury temple of the demo: fused points, the share inside the
  object's bounding box (its README), and the share of points that project onto the object in each
  photo (the background is black: the object is where the photo is brighter than :data:`DARK`).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_dilation

from mvsformerpp.evaluation.calibration import FUSION_BETA, pick_threshold
from mvsformerpp.evaluation.cloud import cloud_distances, evaluate_clouds, f_score
from mvsformerpp.evaluation.depth import grid_artifact_ratio
from mvsformerpp.evaluation.grids import on_coarse_grid
from mvsformerpp.fusion import get_config
from mvsformerpp.fusion.config import METHODS
from mvsformerpp.io.images import read_image
from mvsformerpp.io.middlebury import find_par_file, read_bounding_box, read_par
from mvsformerpp.io.mvsnet import read_cam
from mvsformerpp.io.output_folder import open_run
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_points, read_ply
from mvsformerpp.pipelines.demo import DEMO_CONFIG, run_demo, temple_dir
from mvsformerpp.pipelines.fuse import fuse
from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct
from mvsformerpp.synth import generate_scene

HELDOUT_SEED = 5_000_000
"""First scene seed of the held-out synthetic evaluation (far from every training and validation seed)."""
CALIBRATION_SEED = 2_000_000
"""First scene seed of the fusion-threshold calibration (no training, validation or evaluation seed)."""
WINDOWS = (400.0, 2400.0)
"""Sensor widths (pixels) of the photos whose windows make the ``windows`` kinds of synthetic views (the
focal lengths of real cameras at their working size; :func:`~mvsformerpp.synth.generate_scene`)."""
SYNTHETIC_KINDS = (("train", None), ("heldout", None), ("train", WINDOWS), ("heldout", WINDOWS))
"""The kinds of synthetic scenes (style, sensor widths) the quality check measures and
:func:`calibrate_fusion_conf` fuses; :func:`kind_name` names them."""
CONF_GRID = tuple(round(0.05 * k, 2) for k in range(1, 15))
"""Confidence thresholds tried by :func:`calibrate_fusion_conf` (0.05 .. 0.7)."""
DARK = 20
"""Temple photos: pixels whose brightest channel is at most this (of 255) are background."""


CONF_BINS = tuple(round(0.1 * k, 1) for k in range(11))
"""Edges of the confidence bins of :func:`synthetic_quality`'s calibration table."""


def kind_name(style: str, sensor_width) -> str:
    """``train``, ``heldout``, ``train_windows``, ``heldout_windows``: a kind of :data:`SYNTHETIC_KINDS`."""
    return style if sensor_width is None else f"{style}_windows"


def synthetic_quality(out_dir: str | Path, config: ReconstructConfig, style: str = "train", scenes: int = 4,
                      seed: int = HELDOUT_SEED, num_views: int = 5, height: int = 192, width: int = 256,
                      quiet: bool = True, sensor_width: tuple[float, float] | None = None,
                      layout: str | None = None, plain_walls: float = 0.0,
                      prepare: Callable[[Path], None] | None = None, max_size: int | None = None) -> dict:
    """Depth and cloud quality on ``scenes`` synthetic scenes of ``style`` (module docstring); with
    ``sensor_width`` the views are windows of photos that wide (real cameras' focal lengths); ``layout``
    (training style): only scenes of that layout (``room``: indoor video from a handheld camera);
    ``plain_walls`` (training style): the share of walls and ceilings painted one colour; ``prepare``:
    called with each scene's folder before it is reconstructed (to degrade its photos or change its cam
    files as real captures differ: ``bench/degradations.py``; the truth stays as rendered); ``max_size``:
    the working size (longer side; default the photos' own), the depth maps compared at the photos' size,
    as ``reconstruct`` writes them. Besides
    the shares within 1 % of the range and 10 % of the depth, the median over the valid pixels of the
    relative error |d - d*| / d* (``median_abs_rel``, as indoor benchmarks report it).

    Also the confidence calibration: for each bin of :data:`CONF_BINS`, its share of the valid pixels and
    the share of those within 1 % of the depth range (a confidence that means something rises with it)."""
    out = Path(out_dir)
    cfg = dataclasses.replace(config, max_size=max_size or max(height, width), output_resolution="original",
                              num_views=min(config.num_views, num_views))
    tally, rows = _DepthTally(), []
    for k in range(scenes):
        scene_dir = generate_scene(out / f"scene_{k}", seed=seed + k, num_views=num_views, height=height,
                                   width=width, style=style, sensor_width=sensor_width, layout=layout,
                                   plain_walls=plain_walls)
        if prepare is not None:
            prepare(scene_dir)
        reconstruct(scene_dir, out / f"recon_{k}", cfg, quiet=quiet)
        rows.append({"seed": seed + k, **_scene_quality(scene_dir, out / f"recon_{k}", tally)})
    acc = [r["accuracy_pct"] for r in rows if "accuracy_pct" in r]
    comp = [r["completeness_pct"] for r in rows if "completeness_pct" in r]
    return {"style": style, "scenes": scenes, "first_seed": seed, "size": [height, width], "views": num_views,
            "sensor_width": None if sensor_width is None else list(sensor_width),
            "layout": layout, "plain_walls": plain_walls, **tally.shares(),
            "accuracy_pct": float(np.mean(acc)) if acc else None,
            "completeness_pct": float(np.mean(comp)) if comp else None,
            "per_scene": rows}


class _DepthTally:
    """Depth errors of all scenes of :func:`synthetic_quality`: pixels within 1 % of the range and 10 % of
    the depth, relative errors, and the confidence bins' counts."""

    def __init__(self):
        bins = len(CONF_BINS) - 1
        self.within = self.within10 = self.total = 0
        self.rel: list[np.ndarray] = []
        self.bin_pixels, self.bin_within = np.zeros(bins, np.int64), np.zeros(bins, np.int64)

    def add(self, err: np.ndarray, gt: np.ndarray, conf: np.ndarray, tol: float) -> tuple[int, int]:
        """One view's errors ``err`` at its valid pixels (truth ``gt``, confidence ``conf``) with the range
        tolerance ``tol``; returns (within 1 % of the range, within 10 % of the depth)."""
        bins = len(CONF_BINS) - 1
        close = err < tol
        which = np.clip(np.digitize(conf, CONF_BINS[1:-1]), 0, bins - 1)
        self.bin_pixels += np.bincount(which, minlength=bins)
        self.bin_within += np.bincount(which, weights=close, minlength=bins).astype(np.int64)
        counts = int(close.sum()), int((err < 0.1 * gt).sum())
        self.within, self.within10, self.total = self.within + counts[0], self.within10 + counts[1], \
            self.total + len(gt)
        return counts

    def shares(self) -> dict:
        b = self.bin_pixels
        calibration = [{"conf": [CONF_BINS[i], CONF_BINS[i + 1]], "share": float(b[i] / self.total),
                        "within_1pct": float(self.bin_within[i] / b[i]) if b[i] else None} for i in range(len(b))]
        return {"within_1pct": self.within / self.total, "within_10pct_depth": self.within10 / self.total,
                "median_abs_rel": float(np.median(np.concatenate(self.rel))), "confidence_calibration": calibration}


def _scene_quality(scene_dir: Path, rec: Path, tally: _DepthTally) -> dict:
    """One scene's row of :func:`synthetic_quality`: its depth shares (added to ``tally`` too) and its fused
    cloud's accuracy and completeness against the true surface, in % of the mean true depth."""
    run = open_run(rec)
    within = within10 = total = 0
    depths, rel = [], []
    for view in run.views:
        gt = read_pfm(scene_dir / "depth_gt" / f"{view.stem}.pfm")
        cam = read_cam(scene_dir / "cams" / f"{view.stem}_cam.txt")
        valid = gt > 0
        err = np.abs(view.read_depth()[valid] - gt[valid])
        w1, w10 = tally.add(err, gt[valid], view.read_confidence()[valid], 0.01 * (cam.depth_max - cam.depth_min))
        within, within10, total = within + w1, within10 + w10, total + int(valid.sum())
        depths.append(gt[valid])
        rel.append(err / gt[valid])
    rel = np.concatenate(rel)
    tally.rel.append(rel)
    pred = ply_points(read_ply(run.cloud)).astype(np.float64)
    row = {"within_1pct": within / total, "within_10pct_depth": within10 / total,
           "median_abs_rel": float(np.median(rel)), "points": int(len(pred))}
    if len(pred):
        mean_depth = float(np.concatenate(depths).mean())
        d = cloud_distances(pred, ply_points(read_ply(scene_dir / "gt_surface.ply")).astype(np.float64))
        row["accuracy_pct"] = 100 * float(d.pred_to_gt.mean()) / mean_depth
        row["completeness_pct"] = 100 * float(d.gt_to_pred.mean()) / mean_depth
    return row


def calibrate_fusion_conf(out_dir: str | Path, config: ReconstructConfig, scenes: int = 4,
                          seed: int = CALIBRATION_SEED, methods=tuple(METHODS),
                          grid=CONF_GRID, tau_pct: float = 1.0, num_views: int = 5, height: int = 192,
                          width: int = 256, kinds=SYNTHETIC_KINDS, quiet: bool = True) -> dict:
    """For each fusion method, the confidence threshold of ``grid`` whose fused clouds have the best mean
    F_beta (:data:`FUSION_BETA`) at ``tau_pct`` % of the mean scene depth, on ``scenes`` synthetic scenes
    (seeds ``seed ..``) of each of ``kinds`` ((style, sensor width range or None) pairs: by default the
    four kinds the quality check measures) reconstructed with ``config``'s network."""

    out = Path(out_dir)
    folders = []
    cfg = dataclasses.replace(config, max_size=max(height, width), num_views=min(config.num_views, num_views),
                              fusion="none")
    for style, sensor_width in kinds:
        name = kind_name(style, sensor_width)
        for k in range(scenes):
            scene_dir = generate_scene(out / f"{name}_scene_{k}", seed=seed + k, num_views=num_views, height=height,
                                       width=width, style=style, sensor_width=sensor_width)
            reconstruct(scene_dir, out / f"{name}_recon_{k}", cfg, quiet=quiet)
            folders.append((scene_dir, out / f"{name}_recon_{k}"))
    return {"scenes": scenes, "kinds": [[style, None if sw is None else list(sw)] for style, sw in kinds],
            "first_seed": seed, "size": [height, width], "views": num_views,
            **choose_fusion_conf(folders, methods, grid, tau_pct)}


def choose_fusion_conf(folders, methods=tuple(METHODS), grid=CONF_GRID,
                       tau_pct: float = 1.0, beta: float = FUSION_BETA) -> dict:
    """The F-score sweep of :func:`calibrate_fusion_conf` over (synthetic scene, depth-map folder) pairs:
    ``{"fusion_conf": {method: threshold}, "tau_pct", "beta", "table": {method: [rows per threshold]}}``
    (each row: the mean precision, recall, F-score and F_beta over the scenes); the threshold of each
    method is :func:`pick_threshold`'s."""


    truth = []
    for scene_dir, _ in folders:
        depths = [read_pfm(p) for p in sorted((Path(scene_dir) / "depth_gt").glob("*.pfm"))]
        mean_depth = float(np.concatenate([d[d > 0] for d in depths]).mean())
        truth.append((ply_points(read_ply(Path(scene_dir) / "gt_surface.ply")).astype(np.float64), mean_depth))
    table, best = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        ply = Path(tmp) / "cloud.ply"
        for method in methods:
            rows = []
            for conf in grid:
                scores = []
                for (_, depth_dir), (gt, mean_depth) in zip(folders, truth):
                    fuse(depth_dir, ply, get_config(method, conf_threshold=conf), quiet=True, normals=False,
                         explain_empty=False)
                    pred = ply_points(read_ply(ply)).astype(np.float64)
                    if len(pred) == 0:
                        scores.append((0.0, 0.0, 0.0, 0.0))
                        continue
                    m = evaluate_clouds(pred, gt, tau_pct / 100 * mean_depth)
                    scores.append((m.precision, m.recall, m.f_score, f_score(m.precision, m.recall, beta)))
                p, r, f, fb = (float(np.mean(col)) for col in zip(*scores))
                rows.append({"conf": conf, "precision": p, "recall": r, "f_score": f, "f_beta": fb})
            table[method] = rows
            best[method] = pick_threshold(rows)
    return {"fusion_conf": best, "tau_pct": tau_pct, "beta": beta, "table": table}


def dtu_pair_quality(pair_dir: str | Path, out_dir: str | Path, config: ReconstructConfig,
                     quiet: bool = True) -> dict:
    """Depth of the reference view of the DTU pair (640x512 photos, 160x128 ground truth in mm).

    The prediction at 640x512 is compared on the ground truth's grid by :func:`on_coarse_grid`: depth pixel
    j lies on photo pixel 4j (the cams' K is for the 160x128 grid, scaled by 4 for the photos in integer pixel
    coordinates, as the training pipeline's ``depth[::4, ::4]``; the photos agree best with the ground truth
    placed there, ``tests/geometry/test_geometry.py``), not at the centre of the 4x4 block, 1.5 px away.
    """

    pair_dir, out = Path(pair_dir), Path(out_dir)
    scene = out / "input"
    for d in ("images", "cams"):
        (scene / d).mkdir(parents=True, exist_ok=True)
    for i in (0, 1):
        shutil.copyfile(pair_dir / f"rect_{i + 1:03d}_0_r5000.png", scene / "images" / f"{i:08d}.png")
        shutil.copyfile(pair_dir / f"{i:08d}_cam.txt", scene / "cams" / f"{i:08d}_cam.txt")
    (scene / "pair.txt").write_text("2\n0\n1 1 1.0\n1\n1 0 1.0\n")
    cfg = dataclasses.replace(config, num_views=2, max_size=640, fusion="none")
    reconstruct(scene, out / "recon", cfg, quiet=quiet)
    views = open_run(out / "recon").views
    return dtu_pair_metrics(pair_dir, [views[i].read_depth() for i in (0, 1)])


def dtu_pair_metrics(pair_dir: str | Path, estimates: list[np.ndarray]) -> dict:
    """The DTU pair's measures of the two views' depth maps at 640x512 (see :func:`dtu_pair_quality`)."""
    rows = {}
    for i, est in enumerate(estimates):
        gt = read_pfm(Path(pair_dir) / f"depth_map_{i:04d}.pfm")
        h, w = gt.shape
        near_gt = np.kron(gt > 0, np.ones((4, 4), bool))[: est.shape[0], : est.shape[1]]
        grid, grid32 = grid_artifact_ratio(est, 8, near_gt), grid_artifact_ratio(est, 32, near_gt)
        est = on_coarse_grid(est, (h, w), 4)
        valid = gt > 0
        err = np.abs(est[valid] - gt[valid])
        rows[f"view{i}"] = {"within_4mm": float((err < 4).mean()), "within_8mm": float((err < 8).mean()),
                            "within_10pct": float((err < 0.1 * gt[valid]).mean()),
                            "mae_mm": float(err.mean()), "valid_pixels": int(valid.sum()), "grid_ratio": grid,
                            "grid_ratio_32": grid32}
    keys = ("within_4mm", "within_8mm", "within_10pct", "grid_ratio", "grid_ratio_32")
    return {**{k: float(np.mean([r[k] for r in rows.values()])) for k in keys},
            **rows}


def temple_quality(out_dir: str | Path, config: ReconstructConfig | None = None, quiet: bool = True) -> dict:
    """Reconstruct the bundled temple (the demo's settings unless ``config``) and check the cloud."""

    summary = run_demo(out_dir, config or DEMO_CONFIG, quiet=quiet)
    return {**temple_cloud_metrics(open_run(out_dir).cloud), "views": summary["views"],
            "depth_s": summary["timings"]["depth_s"], "grid_ratio": temple_grid_ratio(out_dir),
            "grid_ratio_32": temple_grid_ratio(out_dir, 32)}


def temple_grid_ratio(out_dir: str | Path, cell: int = 8) -> float:
    """Median over the views of :func:`~mvsformerpp.evaluation.depth.grid_artifact_ratio` of the temple's
    depth maps on a ``cell``-pixel grid (8: stage-1 cells; 32: the stage-1 transformer's token patches),
    on the object (photo pixels brighter than :data:`DARK`)."""

    out = Path(out_dir)
    ratios = []
    for view in open_run(out).views:
        if view.depth is None:
            continue
        depth, image = view.read_depth(), view.read_image()
        mask = image.max(2) > DARK if image is not None else None
        if mask is not None and mask.shape != depth.shape:
            mask = None
        ratios.append(grid_artifact_ratio(depth, cell, mask))
    return float(np.nanmedian(ratios)) if ratios else float("nan")


def temple_cloud_metrics(ply: str | Path) -> dict:
    """Points of a temple cloud, the share inside the README's bounding box, and the mean share (over the
    16 photos) of the points in front of a camera and inside its image that fall on the object."""


    pts = ply_points(read_ply(ply)).astype(np.float64)
    box = read_bounding_box(temple_dir())
    inside = np.all((pts >= box[0]) & (pts <= box[1]), axis=1) if len(pts) else np.zeros(0, bool)
    on_object = []
    for name, K, R, t in read_par(find_par_file(temple_dir())):
        image = read_image(temple_dir() / name)
        mask = binary_dilation(image.max(2) > DARK, iterations=3)
        cam = pts @ R.T + t
        front = cam[:, 2] > 0
        uv = cam[front] @ K.T
        u, v = np.floor(uv[:, 0] / uv[:, 2]).astype(np.int64), np.floor(uv[:, 1] / uv[:, 2]).astype(np.int64)
        h, w = mask.shape
        seen = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        if seen.any():
            on_object.append(float(mask[v[seen], u[seen]].mean()))
    return {"points": int(len(pts)), "inside_box": float(inside.mean()) if len(pts) else 0.0,
            "on_silhouette": float(np.mean(on_object)) if on_object else 0.0}
