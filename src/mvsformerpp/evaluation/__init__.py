"""Evaluation: depth metrics, point-cloud metrics, DTU, Tanks-and-Temples and ETH3D protocols."""

from mvsformerpp.evaluation.cloud import (
    CloudMetrics,
    compare_clouds,
    load_points,
    nearest_distances,
    voxel_downsample,
    write_error_cloud,
)
from mvsformerpp.evaluation.depth import depth_metrics, evaluate_depth_folders
from mvsformerpp.evaluation.dtu import DTU_TEST_SCANS, DTUResult, evaluate_dtu_scan, thin_points
from mvsformerpp.evaluation.eth3d import evaluate_eth3d
from mvsformerpp.evaluation.tnt import TNT_THRESHOLDS, evaluate_tnt, package_submission

__all__ = [
    "CloudMetrics", "DTUResult", "DTU_TEST_SCANS", "TNT_THRESHOLDS", "compare_clouds", "depth_metrics",
    "evaluate_depth_folders", "evaluate_dtu_scan", "evaluate_eth3d", "evaluate_tnt", "load_points",
    "nearest_distances", "package_submission", "thin_points", "voxel_downsample", "write_error_cloud",
]
