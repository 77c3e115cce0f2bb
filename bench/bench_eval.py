"""Point-cloud evaluation time: a 1-2 M point prediction against a 2-3 M point ground truth.

    python bench/bench_eval.py [--pred 1500000] [--gt 2500000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from mvsformerpp.evaluation import compare_clouds, thin_points, voxel_downsample


def surface(n: int, rng) -> np.ndarray:
    """Points on a wavy 400 x 400 mm surface (DTU-like units)."""
    xy = rng.uniform(0, 400, size=(n, 2))
    z = 20 * np.sin(xy[:, 0] / 30) * np.cos(xy[:, 1] / 40)
    return np.c_[xy, z]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pred", type=int, default=1_500_000)
    ap.add_argument("--gt", type=int, default=2_500_000)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    gt = surface(a.gt, rng)
    pred = surface(a.pred, rng) + rng.normal(0, 0.3, (a.pred, 3))
    print(f"prediction {a.pred:,} points, ground truth {a.gt:,} points")
    rows = []
    t = time.perf_counter()
    m, _, _ = compare_clouds(pred, gt, threshold=1.0)
    rows.append(("P/R/F + acc/comp (KD-trees both ways)", time.perf_counter() - t))
    t = time.perf_counter()
    keep = thin_points(pred, 0.2)
    rows.append((f"DTU 0.2 mm thinning ({len(keep):,} kept)", time.perf_counter() - t))
    t = time.perf_counter()
    voxel_downsample(gt, 0.5)
    rows.append(("voxel downsampling of the GT (0.5)", time.perf_counter() - t))
    for name, s in rows:
        print(f"{name:<45} {s:>7.2f} s")
    print(f"F-score {m.f_score:.3f}, accuracy {m.accuracy:.3f}, completeness {m.completeness:.3f}")


if __name__ == "__main__":
    main()
