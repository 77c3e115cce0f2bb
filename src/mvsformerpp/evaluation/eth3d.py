"""ETH3D-style multi-tolerance evaluation: accuracy, completeness and F1 at several tolerances.

Accuracy at tolerance t = share of reconstructed points within t of the GT cloud; completeness = share
of GT points within t of the reconstruction; F1 their harmonic mean (Schoeps et al. 2017, point-to-point
form: the benchmark's own tool additionally weights by GT voxel occupancy and ignores unobserved space).
"""

from __future__ import annotations

import numpy as np

from mvsformerpp.evaluation.cloud import curves, nearest_distances

ETH3D_TOLERANCES = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)  # metres


def evaluate_eth3d(pred: np.ndarray, gt: np.ndarray, tolerances=ETH3D_TOLERANCES) -> list[dict]:
    d_pred, d_gt = nearest_distances(pred, gt), nearest_distances(gt, pred)
    return [{"tolerance": m.threshold, "accuracy": m.precision, "completeness": m.recall, "f1": m.f_score}
            for m in curves(d_pred, d_gt, tolerances)]
