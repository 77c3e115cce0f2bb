"""Evaluation: depth-map metrics and point-cloud metrics (generic, DTU, Tanks-and-Temples, ETH3D).

Everything runs on numpy + scipy (KD-trees, chunked queries); the results are deterministic.
"""

from mvsformerpp.evaluation.cloud import (
    CloudDistances,
    CloudMetrics,
    cloud_distances,
    evaluate_cloud_files,
    evaluate_clouds,
)
from mvsformerpp.evaluation.depth import DepthReport, depth_sums, evaluate_depth_dirs, format_depth_table
from mvsformerpp.evaluation.distances import check_points, load_cloud, nearest_distances
from mvsformerpp.evaluation.dtu import (
    DTU_TEST_SCANS,
    DTUDistances,
    DTUResult,
    ObsMask,
    dtu_distances,
    dtu_mean,
    evaluate_dtu_points,
    evaluate_dtu_scan,
    format_dtu_table,
    load_obs_mask,
    load_plane,
    summarize_dtu,
    write_dtu_error_clouds,
)
from mvsformerpp.evaluation.eth3d import ETH3D_TOLERANCES, ETH3DRow, evaluate_eth3d, evaluate_eth3d_points
from mvsformerpp.evaluation.icp import icp_refine
from mvsformerpp.evaluation.thinning import thin_points, voxel_downsample
from mvsformerpp.evaluation.tnt import (
    TNT_THRESHOLDS,
    CropVolume,
    TnTResult,
    evaluate_tnt,
    evaluate_tnt_points,
    load_crop_volume,
)
from mvsformerpp.evaluation.tnt_submission import package_tnt_submission, read_log, write_log
from mvsformerpp.evaluation.visualize import error_colors, plot_per_scan, plot_pr_curves, write_error_ply

__all__ = [
    "DTU_TEST_SCANS", "ETH3D_TOLERANCES", "TNT_THRESHOLDS", "CloudDistances", "CloudMetrics", "CropVolume",
    "DTUDistances", "DTUResult", "DepthReport", "ETH3DRow", "ObsMask", "TnTResult", "check_points", "cloud_distances",
    "depth_sums", "dtu_distances", "dtu_mean", "error_colors", "evaluate_cloud_files", "evaluate_clouds",
    "evaluate_depth_dirs", "evaluate_dtu_points", "evaluate_dtu_scan", "evaluate_eth3d", "evaluate_eth3d_points",
    "evaluate_tnt", "evaluate_tnt_points", "format_depth_table", "format_dtu_table", "icp_refine", "load_cloud",
    "load_crop_volume",
    "load_obs_mask", "load_plane", "nearest_distances", "package_tnt_submission", "plot_per_scan", "plot_pr_curves",
    "read_log", "summarize_dtu", "thin_points", "voxel_downsample", "write_dtu_error_clouds", "write_error_ply",
    "write_log",
]
