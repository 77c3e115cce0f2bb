"""Tanks-and-Temples evaluation: crop volume, alignment, voxel downsampling, precision/recall/F-score.

Mirrors the official toolbox (``python_toolbox/evaluation``, Knapitsch et al. 2017) without Open3D:

1. the reconstruction is mapped into the ground-truth frame by the given 4x4 ``alignment``
   (the toolbox's ``{scene}_trans.txt``); optionally refined as the toolbox does (``refine``: three
   rounds of point-to-point ICP with scale, :mod:`.icp`;
   the toolbox's camera-trajectory registration is not reproduced: the reconstruction must use the
   benchmark's camera poses, as submissions do);
2. both clouds are cropped by the scene's crop volume (``{scene}.json``, an Open3D
   ``SelectionPolygonVolume``: a polygon in the plane orthogonal to ``orthogonal_axis`` and an
   interval ``[axis_min, axis_max]`` along it);
3. both are voxel-downsampled with voxel size ``threshold / 2`` the way Open3D's
   ``voxel_down_sample`` does (grid anchored at ``min_bound - voxel/2``, one averaged point per voxel);
4. precision / recall / F-score at ``threshold`` from the two directed distance sets (:mod:`.cloud`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.evaluation.cloud import CloudDistances, CloudMetrics, cloud_distances
from mvsformerpp.evaluation.distances import check_points, load_cloud
from mvsformerpp.evaluation.icp import icp_refine
from mvsformerpp.evaluation.thinning import voxel_downsample

#: The official per-scene thresholds (metres), training and intermediate/advanced scenes.
TNT_THRESHOLDS: dict[str, float] = {
    "Barn": 0.01, "Caterpillar": 0.005, "Church": 0.025, "Courthouse": 0.025, "Ignatius": 0.003,
    "Meetingroom": 0.01, "Truck": 0.005,
}
_AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclass(frozen=True)
class CropVolume:
    """A prism: ``polygon`` [K,2] in the two axes other than ``axis``, extruded over [axis_min, axis_max]."""

    axis: int  #: 0, 1 or 2 (the JSON's orthogonal_axis X, Y or Z)
    axis_min: float
    axis_max: float
    polygon: np.ndarray  #: [K,2] vertices, in the order of the remaining axes (e.g. x,y for Z)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """[N] bool: inside the interval along ``axis`` and inside the polygon (even-odd rule)."""
        h = points[:, self.axis]
        uv = np.delete(points, self.axis, axis=1)
        inside = np.zeros(len(points), dtype=bool)
        poly = self.polygon
        for k in range(len(poly)):
            (x1, y1), (x2, y2) = poly[k], poly[k - 1]
            crosses = (y1 > uv[:, 1]) != (y2 > uv[:, 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                x_at = x1 + (uv[:, 1] - y1) * (x2 - x1) / (y2 - y1)
            inside ^= crosses & (uv[:, 0] < x_at)
        return inside & (h >= self.axis_min) & (h <= self.axis_max)


def load_crop_volume(path: str | Path) -> CropVolume:
    """Read a Tanks-and-Temples crop file (``{scene}.json``)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise InputError(f"cannot read the crop volume file ({e.strerror})", path) from e
    except json.JSONDecodeError as e:
        raise FormatError(f"the crop volume is not valid JSON ({e})", path) from e
    try:
        axis = _AXES[str(data["orthogonal_axis"]).upper()]
        poly3 = np.asarray(data["bounding_polygon"], dtype=np.float64)
        lo, hi = float(data["axis_min"]), float(data["axis_max"])
    except (KeyError, TypeError, ValueError) as e:
        raise FormatError("a crop volume needs 'orthogonal_axis' (X/Y/Z), 'bounding_polygon' ([[x,y,z], ...]), "
                          f"'axis_min' and 'axis_max' ({e!r})", path) from e
    if poly3.ndim != 2 or poly3.shape[1] != 3 or len(poly3) < 3:
        raise FormatError(f"'bounding_polygon' must hold at least 3 [x,y,z] points, got shape {poly3.shape}", path)
    return CropVolume(axis=axis, axis_min=lo, axis_max=hi, polygon=np.delete(poly3, axis, axis=1))


def load_alignment(path: str | Path) -> np.ndarray:
    """Read a 4x4 transform as whitespace-separated text (the toolbox's ``{scene}_trans.txt``)."""
    path = Path(path)
    try:
        m = np.loadtxt(path, dtype=np.float64)
    except OSError as e:
        raise InputError(f"cannot read the alignment file ({e})", path) from e
    except ValueError as e:
        raise FormatError(f"the alignment must be 4 rows of 4 numbers ({e})", path) from e
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise FormatError(f"the alignment must be a finite 4x4 matrix, got shape {m.shape}", path)
    det = float(np.linalg.det(m[:3, :3]))
    if not abs(det) > 1e-12 or np.any(m[3] != [0, 0, 0, 1]):
        raise FormatError(f"the alignment is not an invertible similarity transform (det of its 3x3 part {det:g}, "
                          f"last row {m[3].tolist()}); it would collapse the cloud", path)
    return m


def apply_transform(points: np.ndarray, transform: np.ndarray) -> np.ndarray:
    """points [N,3] -> ``(T @ [X,1])[:3]`` for a 4x4 (similarity or rigid) ``transform``."""
    return points @ transform[:3, :3].T + transform[:3, 3]


@dataclass(frozen=True)
class TnTResult:
    """Metrics plus the distance sets (for curves and error-coloured clouds) of one scene."""

    metrics: CloudMetrics
    distances: CloudDistances
    pred_points: np.ndarray  #: [N,3] the evaluated (aligned, cropped, downsampled) prediction
    gt_points: np.ndarray  #: [M,3] the evaluated ground truth


def evaluate_tnt_points(
    pred: np.ndarray,
    gt: np.ndarray,
    threshold: float,
    crop: CropVolume | None = None,
    alignment: np.ndarray | None = None,
    refine: bool = False,
) -> TnTResult:
    """The toolbox protocol on arrays (see the module docstring); voxel size = threshold / 2.

    refine: before scoring, refine the alignment as the toolbox does (:func:`.icp.icp_refine`:
    point-to-point ICP with scale over its three rounds, on the cropped clouds); the prediction must
    already be roughly aligned (within about 80 thresholds).
    """
    pred = check_points(pred, "prediction")
    gt = check_points(gt, "ground truth")
    if alignment is not None:
        pred = apply_transform(pred, np.asarray(alignment, dtype=np.float64))
    if refine:
        pred = apply_transform(pred, icp_refine(pred, gt, threshold, crop=None if crop is None else crop.contains))
    if crop is not None:
        pred, gt = pred[crop.contains(pred)], gt[crop.contains(gt)]
        if len(pred) == 0:
            raise InputError("no prediction point lies inside the crop volume; check the alignment transform")
        if len(gt) == 0:
            raise InputError("no ground-truth point lies inside the crop volume; is it the right scene's crop file?")
    pred, gt = voxel_downsample(pred, threshold / 2), voxel_downsample(gt, threshold / 2)
    dist = cloud_distances(pred, gt)
    return TnTResult(metrics=dist.metrics(threshold), distances=dist, pred_points=pred, gt_points=gt)


def scene_threshold(scene: str | None, threshold: float | None) -> float:
    """The user's threshold, else the official one of ``scene``; a clear error if neither is known."""
    if threshold is not None:
        if not threshold > 0:
            raise InputError(f"the threshold must be positive, got {threshold}")
        return float(threshold)
    if scene in TNT_THRESHOLDS:
        return TNT_THRESHOLDS[scene]
    raise InputError(f"no official threshold for scene {scene!r} (known: {', '.join(TNT_THRESHOLDS)}); "
                     "give one with --threshold")


def evaluate_tnt(
    pred_ply: str | Path,
    gt_ply: str | Path,
    scene: str | None = None,
    threshold: float | None = None,
    crop_json: str | Path | None = None,
    alignment_txt: str | Path | None = None,
    refine: bool = False,
) -> TnTResult:
    """Evaluate a reconstruction PLY against a Tanks-and-Temples ground-truth PLY (metres)."""
    tau = scene_threshold(scene, threshold)
    crop = load_crop_volume(crop_json) if crop_json is not None else None
    alignment = load_alignment(alignment_txt) if alignment_txt is not None else None
    return evaluate_tnt_points(load_cloud(pred_ply, "prediction"), load_cloud(gt_ply, "ground truth"), tau,
                               crop=crop, alignment=alignment, refine=refine)
