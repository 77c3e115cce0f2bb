"""Tanks-and-Temples evaluation (Knapitsch et al. 2017) and submission packaging, without Open3D.

As the official toolbox: the prediction is transformed by the scene's alignment (``<scene>_trans.txt``),
both clouds are cropped to the scene's crop volume (``<scene>.json``, a polygon prism along one axis)
and voxel-downsampled to half the threshold; precision = share of predicted points within the threshold
of the GT, recall = share of GT points within it of the prediction, F = their harmonic mean. (The
toolbox also refines the alignment with ICP against the GT trajectory; we use the given transform.)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.evaluation.cloud import CloudMetrics, compare_clouds, load_points, voxel_downsample
from mvsformerpp.io.scene import Scene
from mvsformerpp.utils.atomic import atomic_write_text

# Scene thresholds of the benchmark, in metres.
TNT_THRESHOLDS = {
    "Ignatius": 0.003, "Caterpillar": 0.005, "Truck": 0.005, "Barn": 0.01, "Meetingroom": 0.01,
    "Church": 0.025, "Courthouse": 0.025,
}


def read_transform(path: str | Path) -> np.ndarray:
    path = Path(path)
    try:
        T = np.loadtxt(path, dtype=np.float64)
    except Exception as e:
        raise FormatError(f"cannot read a 4x4 matrix ({e})", path) from e
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise FormatError(f"expected a finite 4x4 matrix, got shape {T.shape}", path)
    return T


def read_crop_volume(path: str | Path) -> dict:
    """Open3D's SelectionPolygonVolume JSON: orthogonal_axis, axis_min, axis_max, bounding_polygon."""
    path = Path(path)
    try:
        vol = json.loads(path.read_text())
        axis = "XYZ".index(vol["orthogonal_axis"].upper())
        poly = np.asarray(vol["bounding_polygon"], dtype=np.float64)
        return {"axis": axis, "min": float(vol["axis_min"]), "max": float(vol["axis_max"]), "polygon": poly}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise FormatError(f"not a crop-volume file ({e})", path) from e


def crop(points: np.ndarray, volume: dict) -> np.ndarray:
    """Points inside the prism: axis range on the orthogonal axis, point-in-polygon on the other two."""
    a = volume["axis"]
    others = [i for i in range(3) if i != a]
    z = points[:, a]
    keep = (z >= volume["min"]) & (z <= volume["max"])
    px, py = points[:, others[0]], points[:, others[1]]
    poly = volume["polygon"][:, others]
    inside = np.zeros(len(points), dtype=bool)
    n = len(poly)
    for i in range(n):  # even-odd ray casting, vectorised over points
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        crosses = (y1 > py) != (y2 > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = (x2 - x1) * (py - y1) / (y2 - y1) + x1
        inside ^= crosses & (px < xint)
    return points[keep & inside]


def evaluate_tnt(pred: str | Path, gt: str | Path, threshold: float | None = None, scene: str | None = None,
                 transform: str | Path | None = None, crop_file: str | Path | None = None):
    """Precision/recall/F-score of a Tanks-and-Temples reconstruction. Returns (metrics, d_pred, d_gt)."""
    if threshold is None:
        if scene not in TNT_THRESHOLDS:
            raise InputError(f"no threshold given and {scene!r} is not a benchmark scene ({sorted(TNT_THRESHOLDS)})")
        threshold = TNT_THRESHOLDS[scene]
    p, g = load_points(pred), load_points(gt)
    if transform is not None:
        T = read_transform(transform)
        p = p @ T[:3, :3].T + T[:3, 3]
    if crop_file is not None:
        vol = read_crop_volume(crop_file)
        p, g = crop(p, vol), crop(g, vol)
        if len(p) == 0:
            raise InputError("no predicted point lies inside the crop volume (wrong alignment transform?)", pred)
    p, g = voxel_downsample(p, threshold / 2), voxel_downsample(g, threshold / 2)
    return compare_clouds(p, g, threshold)


def format_log(scene: Scene) -> str:
    """The benchmark's .log trajectory: per image ``i i 0`` then the 4x4 camera-to-world pose."""
    lines = []
    for i, v in enumerate(scene.views):
        pose = np.linalg.inv(v.extrinsic)
        lines.append(f"{i} {i} 0")
        lines.extend(" ".join(f"{x:.10f}" for x in row) for row in pose)
    return "\n".join(lines) + "\n"


def package_submission(out_dir: str | Path, reconstructions: dict[str, tuple[str | Path, Scene]]) -> Path:
    """Write a leaderboard folder: ``<Scene>.ply`` and ``<Scene>.log`` for each reconstruction."""
    import shutil

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for name, (ply, scene) in reconstructions.items():
        ply = Path(ply)
        if not ply.is_file():
            raise InputError("reconstruction not found", ply)
        tmp = out / f".{name}.ply.tmp"
        shutil.copyfile(ply, tmp)
        tmp.replace(out / f"{name}.ply")
        atomic_write_text(out / f"{name}.log", format_log(scene))
    return out


__all__ = ["TNT_THRESHOLDS", "CloudMetrics", "crop", "evaluate_tnt", "format_log", "package_submission",
           "read_crop_volume", "read_transform"]
