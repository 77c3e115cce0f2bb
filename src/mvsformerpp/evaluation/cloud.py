"""Point-cloud metrics: nearest-neighbour distances with KD-trees, precision/recall/F-score, accuracy and
completeness, voxel downsampling, error-coloured clouds."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from mvsformerpp.errors import InputError
from mvsformerpp.io.ply import ply_points, read_ply, write_ply


def load_points(path: str | Path) -> np.ndarray:
    """[N,3] float64 points of a PLY file; a clear error for empty clouds or non-finite coordinates."""
    pts = ply_points(read_ply(path), path)
    if len(pts) == 0:
        raise InputError("the point cloud is empty", path)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise InputError(f"{int(bad.sum())} points have NaN or infinite coordinates; remove them first", path)
    return pts


def nearest_distances(query: np.ndarray, reference: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
    """Distance from each query point to its nearest reference point (KD-tree, chunked, all cores)."""
    if len(reference) == 0:
        return np.full(len(query), np.inf)
    tree = cKDTree(reference)
    out = np.empty(len(query))
    for s in range(0, len(query), chunk):
        out[s:s + chunk] = tree.query(query[s:s + chunk], k=1, workers=-1)[0]
    return out


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Mean of the points in each occupied voxel (as Open3D's voxel_down_sample), in voxel order."""
    if voxel <= 0 or len(points) == 0:
        return points
    keys = np.floor((points - points.min(0)) / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse.reshape(-1), points)
    return sums / counts[:, None]


@dataclass
class CloudMetrics:
    threshold: float
    precision: float  # share of predicted points within threshold of the GT
    recall: float  # share of GT points within threshold of the prediction
    f_score: float
    accuracy: float  # mean prediction -> GT distance
    completeness: float  # mean GT -> prediction distance
    num_pred: int
    num_gt: int

    def to_dict(self) -> dict:
        return asdict(self)


def f_score(precision: float, recall: float) -> float:
    return 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)


def cloud_metrics_from_distances(d_pred: np.ndarray, d_gt: np.ndarray, threshold: float) -> CloudMetrics:
    p = float(np.mean(d_pred < threshold)) if len(d_pred) else 0.0
    r = float(np.mean(d_gt < threshold)) if len(d_gt) else 0.0
    return CloudMetrics(threshold, p, r, f_score(p, r), float(np.mean(d_pred)) if len(d_pred) else float("nan"),
                        float(np.mean(d_gt)) if len(d_gt) else float("nan"), len(d_pred), len(d_gt))


def compare_clouds(pred: np.ndarray, gt: np.ndarray, threshold: float) -> tuple[CloudMetrics, np.ndarray, np.ndarray]:
    """Metrics at ``threshold`` plus the two distance arrays (prediction->GT, GT->prediction)."""
    if threshold <= 0:
        raise InputError(f"the threshold must be positive, got {threshold}")
    d_pred, d_gt = nearest_distances(pred, gt), nearest_distances(gt, pred)
    return cloud_metrics_from_distances(d_pred, d_gt, threshold), d_pred, d_gt


def curves(d_pred: np.ndarray, d_gt: np.ndarray, thresholds) -> list[CloudMetrics]:
    return [cloud_metrics_from_distances(d_pred, d_gt, t) for t in thresholds]


def write_error_cloud(path: str | Path, points: np.ndarray, distances: np.ndarray, max_distance: float) -> None:
    """PLY coloured by distance (blue = 0 ... red >= max_distance), with the distance as a property."""
    from mvsformerpp.utils.colormap import turbo

    x = np.clip(distances / max_distance, 0, 1)
    write_ply(path, points.astype(np.float32), turbo(x), extra={"distance": distances.astype(np.float32)})
