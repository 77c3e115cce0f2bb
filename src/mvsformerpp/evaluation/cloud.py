"""Generic point-cloud metrics: precision / recall / F-score at a threshold, accuracy / completeness.

Definitions (Knapitsch et al., "Tanks and Temples", SIGGRAPH 2017, Sec. 4; the same pair of
directed distances underlies the DTU and ETH3D protocols):

- accuracy distances: for each predicted point, the distance to the nearest ground-truth point;
- completeness distances: for each ground-truth point, the distance to the nearest predicted point;
- precision(T) = share of predicted points with accuracy distance < T;
- recall(T) = share of ground-truth points with completeness distance < T;
- F(T) = 2 P R / (P + R) (0 when both are 0);
- accuracy / completeness = mean of the respective distances (the DTU-style "mean distance").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mvsformerpp.evaluation.distances import check_points, load_cloud, nearest_distances


@dataclass(frozen=True)
class CloudMetrics:
    """Metrics of one prediction against one ground truth at one threshold (same length unit)."""

    threshold: float  #: distance under which a point counts as correct
    precision: float  #: share of predicted points within ``threshold`` of the ground truth
    recall: float  #: share of ground-truth points within ``threshold`` of the prediction
    f_score: float  #: harmonic mean of precision and recall
    accuracy: float  #: mean distance prediction -> ground truth
    completeness: float  #: mean distance ground truth -> prediction
    num_pred: int  #: points in the evaluated prediction
    num_gt: int  #: points in the evaluated ground truth

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


@dataclass(frozen=True)
class CloudDistances:
    """The two directed distance sets; every cloud metric is a statistic of these."""

    pred_to_gt: np.ndarray  #: [N_pred] distance of each predicted point to the ground truth
    gt_to_pred: np.ndarray  #: [N_gt] distance of each ground-truth point to the prediction

    def metrics(self, threshold: float) -> CloudMetrics:
        """Precision/recall/F-score at ``threshold`` and the mean distances."""
        if not threshold > 0:
            raise ValueError(f"threshold must be positive, got {threshold}")
        p = float(np.mean(self.pred_to_gt < threshold))
        r = float(np.mean(self.gt_to_pred < threshold))
        return CloudMetrics(
            threshold=float(threshold),
            precision=p,
            recall=r,
            f_score=f_score(p, r),
            accuracy=float(np.mean(self.pred_to_gt)),
            completeness=float(np.mean(self.gt_to_pred)),
            num_pred=len(self.pred_to_gt),
            num_gt=len(self.gt_to_pred),
        )

    def curve(self, thresholds: np.ndarray) -> dict[str, np.ndarray]:
        """Precision, recall and F-score for each of ``thresholds`` [T] (for plots). Sorted-search, O(T log N)."""
        t = np.asarray(thresholds, dtype=np.float64)
        a, c = np.sort(self.pred_to_gt), np.sort(self.gt_to_pred)
        p = np.searchsorted(a, t, side="left") / len(a)
        r = np.searchsorted(c, t, side="left") / len(c)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(p + r > 0, 2 * p * r / (p + r), 0.0)
        return {"thresholds": t, "precision": p, "recall": r, "f_score": f}


def f_score(precision: float, recall: float, beta: float = 1.0) -> float:
    """F-score: the harmonic mean of precision and recall (``beta`` 1); 0 when both are 0.

    Other ``beta`` give the weighted harmonic mean 1/F = (1/P + beta^2/R) / (1 + beta^2): recall
    counts ``beta`` times as much as precision (beta < 1: precision counts more)."""
    b2 = beta * beta
    den = b2 * precision + recall
    return 0.0 if den <= 0 else (1.0 + b2) * precision * recall / den


def cloud_distances(pred: np.ndarray, gt: np.ndarray, max_dist: float = np.inf) -> CloudDistances:
    """Both directed nearest-neighbour distance sets between ``pred`` [N,3] and ``gt`` [M,3]."""
    pred = check_points(pred, "prediction")
    gt = check_points(gt, "ground truth")
    return CloudDistances(
        pred_to_gt=nearest_distances(pred, gt, max_dist=max_dist),
        gt_to_pred=nearest_distances(gt, pred, max_dist=max_dist),
    )


def evaluate_clouds(pred: np.ndarray, gt: np.ndarray, threshold: float) -> CloudMetrics:
    """Precision, recall, F-score at ``threshold`` plus accuracy and completeness (mean distances)."""
    return cloud_distances(pred, gt).metrics(threshold)


def evaluate_cloud_files(pred_path: str | Path, gt_path: str | Path, threshold: float) -> CloudMetrics:
    """:func:`evaluate_clouds` on two PLY files (same length unit as ``threshold``)."""
    return evaluate_clouds(load_cloud(pred_path, "prediction"), load_cloud(gt_path, "ground truth"), threshold)
