"""ETH3D-style multi-tolerance accuracy / completeness / F1 for point clouds (Schöps et al., CVPR 2017).

At each tolerance t (metres; the benchmark's 1, 2, 5, 10, 20 and 50 cm):
accuracy(t) = share of reconstruction points within t of the ground truth, completeness(t) =
share of ground-truth points within t of the reconstruction, F1 = their harmonic mean.
This is the point-count version: the official tool additionally weights by voxelised density and
ignores reconstruction points in unobserved space, which needs its occlusion data.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mvsformerpp.evaluation.cloud import cloud_distances, f_score
from mvsformerpp.evaluation.distances import load_cloud

#: The benchmark's tolerances in metres.
ETH3D_TOLERANCES: tuple[float, ...] = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)


@dataclass(frozen=True)
class ETH3DRow:
    """Scores at one tolerance, all in [0, 1]."""

    tolerance: float
    accuracy: float
    completeness: float
    f1: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def evaluate_eth3d_points(pred: np.ndarray, gt: np.ndarray,
                          tolerances: tuple[float, ...] = ETH3D_TOLERANCES) -> list[ETH3DRow]:
    """Scores of pred [N,3] against gt [M,3] at each tolerance (a point exactly at t counts as within)."""
    dist = cloud_distances(pred, gt, max_dist=np.inf)
    rows = []
    for t in tolerances:
        a = float(np.mean(dist.pred_to_gt <= t))
        c = float(np.mean(dist.gt_to_pred <= t))
        rows.append(ETH3DRow(tolerance=float(t), accuracy=a, completeness=c, f1=f_score(a, c)))
    return rows


def evaluate_eth3d(pred_ply: str | Path, gt_ply: str | Path,
                   tolerances: tuple[float, ...] = ETH3D_TOLERANCES) -> list[ETH3DRow]:
    """:func:`evaluate_eth3d_points` on two PLY files (metres)."""
    return evaluate_eth3d_points(load_cloud(pred_ply, "prediction"), load_cloud(gt_ply, "ground truth"), tolerances)


def format_eth3d_table(rows: list[ETH3DRow]) -> str:
    """Fixed-width table, tolerances in cm, scores in percent."""
    lines = [f"{'tol[cm]':>8} {'acc%':>7} {'comp%':>7} {'F1%':>7}"]
    lines += [f"{r.tolerance * 100:8.1f} {r.accuracy * 100:7.2f} {r.completeness * 100:7.2f} {r.f1 * 100:7.2f}"
              for r in rows]
    return "\n".join(lines)
