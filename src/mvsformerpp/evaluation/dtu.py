"""DTU point-cloud evaluation (Aanaes et al. 2016), the official protocol without MATLAB.

From the official evaluation files in ``DTU_ROOT``: ``ObsMask/ObsMask{N}_10.mat`` (``ObsMask`` 3-D
boolean grid, ``BB`` its 2x3 bounding box, ``Res`` the voxel size), ``ObsMask/Plane{N}.mat`` (``P``,
a plane [a b c d]; GT points with [x y z 1] . P > 0 count), ``Points/stl/stl{NNN}_total.ply``.

1. The prediction is thinned to a minimum spacing of 0.2 mm, greedily in file order (the official
   code visits points in a random order; ours is deterministic).
2. Accuracy: mean distance from the thinned prediction points inside the observation mask to the
   GT points; completeness: mean distance from the GT points above the plane to those prediction
   points; both ignore distances of 20 mm and more. Overall = their mean.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from mvsformerpp.errors import InputError
from mvsformerpp.evaluation.cloud import load_points, nearest_distances

DTU_TEST_SCANS = (1, 4, 9, 10, 11, 12, 13, 15, 23, 24, 29, 32, 33, 34, 48, 49, 62, 75, 77, 110, 114, 118)
MAX_DIST = 20.0
MIN_SPACING = 0.2


@dataclass
class DTUResult:
    scan: int
    accuracy: float
    completeness: float
    overall: float
    num_pred: int  # after thinning, inside the mask
    num_gt: int  # above the plane

    def to_dict(self) -> dict:
        return asdict(self)


def thin_points(points: np.ndarray, spacing: float = MIN_SPACING) -> np.ndarray:
    """Indices of a subset with no two points closer than ``spacing`` (greedy, in input order)."""
    tree = cKDTree(points)
    pairs = tree.query_pairs(spacing, output_type="ndarray")  # i < j
    if len(pairs) == 0:
        return np.arange(len(points))
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    pairs = pairs[order]
    starts = np.searchsorted(pairs[:, 0], np.arange(len(points) + 1))
    keep = np.ones(len(points), dtype=bool)
    for i in np.unique(pairs[:, 0]):  # only points with a close neighbour need a decision
        if keep[i]:
            keep[pairs[starts[i]:starts[i + 1], 1]] = False
    return np.nonzero(keep)[0]


def _loadmat(path: Path) -> dict:
    from scipy.io import loadmat

    if not path.is_file():
        raise InputError("DTU evaluation file not found (download SampleSet/MVS Data Points and ObsMask)", path)
    try:
        return loadmat(path)
    except Exception as e:
        raise InputError(f"cannot read .mat file ({e})", path) from e


def load_dtu_gt(dtu_root: str | Path, scan: int):
    """(obs_mask [X,Y,Z] bool, bb [2,3], res, plane [4], stl points [N,3]) of one scan."""
    root = Path(dtu_root)
    obs = _loadmat(root / "ObsMask" / f"ObsMask{scan}_10.mat")
    for key in ("ObsMask", "BB", "Res"):
        if key not in obs:
            raise InputError(f"{key} missing from the ObsMask file", root / "ObsMask" / f"ObsMask{scan}_10.mat")
    plane = _loadmat(root / "ObsMask" / f"Plane{scan}.mat")
    if "P" not in plane:
        raise InputError("P missing from the plane file", root / "ObsMask" / f"Plane{scan}.mat")
    stl = root / "Points" / "stl" / f"stl{scan:03d}_total.ply"
    if not stl.is_file():
        raise InputError(f"no ground truth for scan {scan}", stl)
    return (np.asarray(obs["ObsMask"]).astype(bool), np.asarray(obs["BB"], dtype=np.float64).reshape(2, 3),
            float(np.asarray(obs["Res"]).reshape(-1)[0]), np.asarray(plane["P"], dtype=np.float64).reshape(4),
            load_points(stl))


def in_observation_mask(points: np.ndarray, mask: np.ndarray, bb: np.ndarray, res: float) -> np.ndarray:
    idx = np.round((points - bb[0]) / res).astype(np.int64)
    inside = np.all((idx >= 0) & (idx < np.array(mask.shape)), axis=1)
    out = np.zeros(len(points), dtype=bool)
    out[inside] = mask[idx[inside, 0], idx[inside, 1], idx[inside, 2]]
    return out


def evaluate_dtu_scan(pred: str | Path | np.ndarray, dtu_root: str | Path, scan: int,
                      spacing: float = MIN_SPACING, max_dist: float = MAX_DIST):
    """DTU metrics of one predicted cloud (PLY path or [N,3] in mm). Returns (result, extras) where
    extras holds the kept prediction points and both distance arrays (for error-coloured clouds)."""
    points = load_points(pred) if not isinstance(pred, np.ndarray) else np.asarray(pred, dtype=np.float64)
    mask, bb, res, plane, stl = load_dtu_gt(dtu_root, scan)
    points = points[thin_points(points, spacing)]
    points = points[in_observation_mask(points, mask, bb, res)]
    if len(points) == 0:
        raise InputError(f"scan {scan}: no predicted point lies inside the observation mask (wrong units or "
                         "coordinate frame? DTU clouds are in millimetres, in the DTU world frame)")
    gt = stl[np.hstack([stl, np.ones((len(stl), 1))]) @ plane > 0]
    d_pred, d_gt = nearest_distances(points, gt), nearest_distances(gt, points)
    acc = float(d_pred[d_pred < max_dist].mean()) if (d_pred < max_dist).any() else float("nan")
    comp = float(d_gt[d_gt < max_dist].mean()) if (d_gt < max_dist).any() else float("nan")
    result = DTUResult(scan, acc, comp, (acc + comp) / 2, len(points), len(gt))
    return result, {"points": points, "d_pred": d_pred, "gt": gt, "d_gt": d_gt}


def dtu_table(results: list[DTUResult]) -> str:
    lines = [f"{'scan':>6} {'acc (mm)':>9} {'comp (mm)':>10} {'overall':>8}"]
    for r in results:
        lines.append(f"{r.scan:>6} {r.accuracy:>9.4f} {r.completeness:>10.4f} {r.overall:>8.4f}")
    if len(results) > 1:
        a = np.mean([r.accuracy for r in results])
        c = np.mean([r.completeness for r in results])
        lines.append(f"{'mean':>6} {a:>9.4f} {c:>10.4f} {(a + c) / 2:>8.4f}")
    return "\n".join(lines)
