"""Benchmark: evaluate a 1-2M point prediction against a 2-3M point ground truth.

Synthetic DTU-like scene in mm: a wavy 200 x 200 mm surface, ground truth sampled on a jittered grid,
prediction = random surface samples + 0.15 mm noise + 2 % outliers. Times each stage of the DTU
protocol (thinning to 0.2 mm, mask lookup, both capped KD-tree distance passes) and the
Tanks-and-Temples / generic protocols on the same clouds, and prints a table.

    PYTHONPATH=src python bench/bench_eval.py [--pred 1500000] [--gt 2500000]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.io

from mvsformerpp.evaluation import ObsMask, evaluate_clouds, evaluate_dtu_scan, evaluate_tnt_points, thin_points
from mvsformerpp.evaluation.distances import nearest_distances
from mvsformerpp.evaluation.dtu import above_plane, in_obs_mask, in_search_blocks
from mvsformerpp.io.ply import write_ply


def surface(xy: np.ndarray) -> np.ndarray:
    z = 5 * np.sin(xy[:, 0] / 15) * np.cos(xy[:, 1] / 20)
    return np.concatenate([xy, z[:, None]], axis=1)


def make_clouds(n_pred: int, n_gt: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    side = int(np.sqrt(n_gt))
    g = (np.arange(side) + 0.5) * (200 / side)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    gt = surface(np.stack([gx.ravel(), gy.ravel()], 1) + rng.normal(scale=0.02, size=(side * side, 2)))
    n_out = n_pred // 50
    pred = surface(rng.uniform(0, 170, size=(n_pred - n_out, 2))) + rng.normal(scale=0.15, size=(n_pred - n_out, 3))
    outliers = rng.uniform([0, 0, -30], [200, 200, 30], size=(n_out, 3))
    return np.concatenate([pred, outliers]), gt


def timed(label: str, rows: list, fn):
    t = time.perf_counter()
    out = fn()
    rows.append((label, time.perf_counter() - t))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pred", type=int, default=1_500_000, help="prediction points")
    ap.add_argument("--gt", type=int, default=2_500_000, help="ground-truth points")
    args = ap.parse_args()
    pred, gt = make_clouds(args.pred, args.gt)
    print(f"prediction {len(pred):,} points, ground truth {len(gt):,} points; "
          f"{os.cpu_count()} CPU cores, {platform.processor() or platform.machine()}")

    rows: list[tuple[str, float]] = []
    keep = timed("DTU: thin to 0.2 mm", rows, lambda: thin_points(pred, 0.2))
    q = pred[keep]
    obs = ObsMask(np.ones((101, 101, 41), bool), np.array([[-5.0, -5, -20], [205, 205, 20]]), 2.0)
    in_mask = timed("DTU: ObsMask lookup", rows, lambda: in_obs_mask(q, obs))
    d_data = timed("DTU: pred -> GT distances", rows, lambda: nearest_distances(q, gt, max_dist=20.0))
    d_stl = timed("DTU: GT -> pred distances", rows, lambda: nearest_distances(gt, q, max_dist=20.0))
    d_data[~in_search_blocks(q, obs.bb, 20.0)] = 20.0
    d_stl[~in_search_blocks(gt, obs.bb, 20.0)] = 20.0
    above = above_plane(gt, np.array([0, 0, 1.0, 100]))
    acc = d_data[in_mask & (d_data < 20)].mean()
    comp = d_stl[above & (d_stl < 20)].mean()
    dtu_total = sum(t for _, t in rows)
    rows.append(("DTU protocol total", dtu_total))
    with tempfile.TemporaryDirectory() as tmp:  # the same scan as official-format files, end to end
        root = Path(tmp)
        (root / "ObsMask").mkdir()
        (root / "Points" / "stl").mkdir(parents=True)
        scipy.io.savemat(root / "ObsMask" / "ObsMask1_10.mat", {"ObsMask": obs.mask, "BB": obs.bb, "Res": obs.res})
        scipy.io.savemat(root / "ObsMask" / "Plane1.mat", {"P": np.array([[0.0], [0], [1], [100]])})
        write_ply(root / "Points" / "stl" / "stl001_total.ply", gt)
        write_ply(root / "pred.ply", pred)
        res = timed("DTU scan from files (read + protocol)", rows,
                    lambda: evaluate_dtu_scan(root / "pred.ply", 1, root))
    m = timed("generic cloud metrics (P/R/F, acc/comp)", rows, lambda: evaluate_clouds(pred, gt, 0.5))
    r = timed("TnT protocol (voxel 0.25, P/R/F at 0.5)", rows, lambda: evaluate_tnt_points(pred, gt, 0.5))

    print(f"\n| {'stage':<42} | {'seconds':>8} |\n|{'-' * 44}|{'-' * 10}|")
    for label, t in rows:
        print(f"| {label:<42} | {t:8.2f} |")
    print(f"\nDTU: kept {keep.sum():,} of {len(pred):,} after thinning; acc {acc:.4f} mm, comp {comp:.4f} mm; "
          f"from files: acc {res.accuracy:.4f} comp {res.completeness:.4f} (float32 PLY coordinates)")
    print(f"generic @0.5 mm: P {m.precision:.4f} R {m.recall:.4f} F {m.f_score:.4f}; "
          f"TnT @0.5 mm: F {r.metrics.f_score:.4f} ({len(r.pred_points):,} / {len(r.gt_points):,} voxels)")


if __name__ == "__main__":
    main()
