"""DTU point-cloud evaluation, the official protocol without MATLAB.

Follows the DTU MVS benchmark's MATLAB code (``BaseEvalMain_web.m``, ``PointCompareMain.m``,
``ComputeStat_web.m``; Aanaes et al., IJCV 2016), with its files read as published:

- ``ObsMask/ObsMask{N}_10.mat``: ``ObsMask`` (3-D logical grid), ``BB`` (2x3: min and max corner,
  mm) and ``Res`` (grid spacing, mm);
- ``ObsMask/Plane{N}.mat``: ``P`` (4-vector); a ground-truth point X is kept when ``P . [X, 1] > 0``;
- ``Points/stl/stl{NNN}_total.ply``: the structured-light ground-truth points (mm).

Steps for one scan: thin the prediction to ``dst`` = 0.2 mm spacing (:mod:`.thinning`);
prediction points whose voxel ``round((X - BB_min) / Res + 1)`` (1-based, MATLAB rounding) is
inside the grid and set in ``ObsMask`` are "in mask"; distances in both directions are capped at
``MaxDist`` = 20 mm (points outside MaxDistCP.m's search blocks around ``BB`` get the cap);
accuracy = mean of the in-mask prediction distances below 20 mm, completeness =
mean of the above-plane ground-truth distances below 20 mm, overall = their mean.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import scipy.io

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.evaluation.distances import check_points, load_cloud, nearest_distances
from mvsformerpp.evaluation.thinning import thin_points
from mvsformerpp.evaluation.visualize import write_error_ply

#: The 22 evaluation scans of the DTU test split used by MVSNet-family papers.
DTU_TEST_SCANS: tuple[int, ...] = (1, 4, 9, 10, 11, 12, 13, 15, 23, 24, 29, 32, 33, 34, 48, 49, 62, 75, 77, 110,
                                   114, 118)
#: Minimum spacing of the thinned prediction, mm (``dst`` in BaseEvalMain_web.m).
DTU_DST = 0.2
#: Distance cap and cut-off, mm (``MaxDist`` / ``Dmax``).
DTU_MAX_DIST = 20.0


@dataclass(frozen=True)
class ObsMask:
    """The observability grid of one scan."""

    mask: np.ndarray  #: [X,Y,Z] bool; voxel (i,j,k) covers BB_min + Res * (i,j,k) (0-based) +- Res/2
    bb: np.ndarray  #: [2,3] float64 bounding box, row 0 = min corner (mm)
    res: float  #: voxel size (mm)


@dataclass(frozen=True)
class DTUResult:
    """One scan's result; distances in mm."""

    scan: int
    accuracy: float  #: mean distance of in-mask prediction points (< MaxDist) to the ground truth
    completeness: float  #: mean distance of above-plane ground-truth points (< MaxDist) to the prediction
    overall: float  #: (accuracy + completeness) / 2
    accuracy_median: float
    completeness_median: float
    num_pred: int  #: prediction points read
    num_pred_thinned: int  #: after thinning to ``dst``
    num_pred_used: int  #: thinned, in the mask and closer than MaxDist (the accuracy average's support)
    num_gt: int  #: ground-truth points read
    num_gt_used: int  #: above the plane and closer than MaxDist (the completeness average's support)

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


def _loadmat(path: Path, keys: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise InputError(f"the DTU {what} file does not exist; download the DTU 'SampleSet' evaluation data "
                         "(ObsMask/ and Points/stl/) and pass its folder", path)
    try:
        data = scipy.io.loadmat(str(path))
    except NotImplementedError as e:  # MATLAB v7.3 files are HDF5
        raise FormatError("MATLAB v7.3 (HDF5) .mat files are not supported; re-save it with save(..., '-v7')",
                          path) from e
    except Exception as e:  # scipy raises ValueError/TypeError/... on corrupt files
        raise FormatError(f"cannot read the .mat file ({e})", path) from e
    missing = [k for k in keys if k not in data]
    if missing:
        raise FormatError(f"the {what} file lacks the variables {missing}", path)
    return data


def load_obs_mask(path: str | Path) -> ObsMask:
    """Read ``ObsMask{N}_10.mat`` (variables ObsMask, BB, Res)."""
    path = Path(path)
    data = _loadmat(path, ("ObsMask", "BB", "Res"), "observation mask")
    mask = np.asarray(data["ObsMask"]).astype(bool)
    bb = np.asarray(data["BB"], dtype=np.float64)
    res = np.asarray(data["Res"], dtype=np.float64).ravel()
    if mask.ndim != 3 or bb.shape != (2, 3) or res.size != 1 or not res[0] > 0:
        raise FormatError(f"expected a 3-D ObsMask, a 2x3 BB and a positive scalar Res; got shapes "
                          f"{mask.shape}, {bb.shape}, {res.shape}", path)
    return ObsMask(mask=mask, bb=bb, res=float(res[0]))


def load_plane(path: str | Path) -> np.ndarray:
    """Read ``Plane{N}.mat`` (variable P, 4 numbers) as a [4] float64 array."""
    path = Path(path)
    p = np.asarray(_loadmat(path, ("P",), "plane")["P"], dtype=np.float64).ravel()
    if p.size != 4 or not np.isfinite(p).all():
        raise FormatError(f"the plane P must be 4 finite numbers, got {p.size} values", path)
    return p


def matlab_round(x: np.ndarray) -> np.ndarray:
    """MATLAB ``round``: halves go away from zero (numpy's ``round`` goes to even)."""
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


def in_obs_mask(points: np.ndarray, obs: ObsMask) -> np.ndarray:
    """[N] bool: the point's voxel lies in the grid and is observed (PointCompareMain.m)."""
    v = matlab_round((points - obs.bb[0]) / obs.res + 1.0) - 1.0  # MATLAB 1-based -> 0-based
    shape = np.asarray(obs.mask.shape)
    inside = np.all((v >= 0) & (v < shape), axis=1)
    out = np.zeros(len(points), dtype=bool)
    idx = v[inside].astype(np.int64)
    out[inside] = obs.mask[idx[:, 0], idx[:, 1], idx[:, 2]]
    return out


def above_plane(points: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """[N] bool: ``P . [X, 1] > 0``."""
    return points @ plane[:3] + plane[3] > 0


def in_search_blocks(points: np.ndarray, bb: np.ndarray, max_dist: float) -> np.ndarray:
    """[N] bool: the point lies in one of the MaxDist-sized blocks that MaxDistCP.m searches.

    The MATLAB routine tiles space from ``BB_min`` with cubes of side ``MaxDist``, ``floor((BB_max -
    BB_min) / MaxDist) + 1`` per axis, and leaves points outside them at distance ``MaxDist``, i.e.
    ignored. Inside the tiling its block-wise search is exact for distances below ``MaxDist``.
    """
    hi = bb[0] + (np.floor((bb[1] - bb[0]) / max_dist) + 1) * max_dist
    return np.all((points >= bb[0]) & (points < hi), axis=1)


def dtu_paths(dtu_root: str | Path, scan: int) -> dict[str, Path]:
    """The official file locations of one scan under the evaluation-data folder."""
    root = Path(dtu_root)
    return {
        "obs_mask": root / "ObsMask" / f"ObsMask{scan}_10.mat",
        "plane": root / "ObsMask" / f"Plane{scan}.mat",
        "stl": root / "Points" / "stl" / f"stl{scan:03d}_total.ply",
    }


@dataclass(frozen=True)
class DTUDistances:
    """The per-point evidence behind a :class:`DTUResult` (for error-coloured clouds)."""

    pred: np.ndarray  #: [N,3] thinned prediction
    pred_dist: np.ndarray  #: [N] capped distance to the ground truth (``Ddata``)
    pred_used: np.ndarray  #: [N] bool: in the mask and below MaxDist
    gt: np.ndarray  #: [M,3] ground truth
    gt_dist: np.ndarray  #: [M] capped distance to the thinned prediction (``Dstl``)
    gt_used: np.ndarray  #: [M] bool: above the plane and below MaxDist


def dtu_distances(
    pred: np.ndarray,
    gt: np.ndarray,
    obs: ObsMask,
    plane: np.ndarray,
    dst: float = DTU_DST,
    max_dist: float = DTU_MAX_DIST,
    seed: int | None = None,
) -> DTUDistances:
    """Thinning, mask, plane and both capped distance passes (BaseEvalMain_web.m + PointCompareMain.m)."""
    pred = check_points(pred, "prediction")
    gt = check_points(gt, "ground truth")
    thinned = pred[thin_points(pred, dst, seed=seed)]
    d_data = nearest_distances(thinned, gt, max_dist=max_dist)
    d_stl = nearest_distances(gt, thinned, max_dist=max_dist)
    d_data[~in_search_blocks(thinned, obs.bb, max_dist)] = max_dist
    d_stl[~in_search_blocks(gt, obs.bb, max_dist)] = max_dist
    return DTUDistances(
        pred=thinned, pred_dist=d_data, pred_used=in_obs_mask(thinned, obs) & (d_data < max_dist),
        gt=gt, gt_dist=d_stl, gt_used=above_plane(gt, plane) & (d_stl < max_dist),
    )


def summarize_dtu(dist: DTUDistances, scan: int = 0, num_pred: int | None = None) -> DTUResult:
    """Means and medians of the used distances (ComputeStat_web.m)."""
    acc, comp = dist.pred_dist[dist.pred_used], dist.gt_dist[dist.gt_used]
    if len(acc) == 0:
        raise InputError(f"scan {scan}: no prediction point lies inside the observation mask within "
                         f"{DTU_MAX_DIST:g} mm of the ground truth; is the cloud in DTU world coordinates (mm)?")
    if len(comp) == 0:
        raise InputError(f"scan {scan}: no ground-truth point lies above the plane within {DTU_MAX_DIST:g} mm "
                         "of the prediction; is the cloud in DTU world coordinates (mm)?")
    a, c = float(acc.mean()), float(comp.mean())
    return DTUResult(
        scan=scan, accuracy=a, completeness=c, overall=(a + c) / 2,
        accuracy_median=float(np.median(acc)), completeness_median=float(np.median(comp)),
        num_pred=len(dist.pred) if num_pred is None else num_pred, num_pred_thinned=len(dist.pred),
        num_pred_used=len(acc), num_gt=len(dist.gt), num_gt_used=len(comp),
    )


def evaluate_dtu_points(
    pred: np.ndarray,
    gt: np.ndarray,
    obs: ObsMask,
    plane: np.ndarray,
    scan: int = 0,
    dst: float = DTU_DST,
    max_dist: float = DTU_MAX_DIST,
    seed: int | None = None,
) -> DTUResult:
    """The DTU protocol on arrays: pred [N,3] and gt [M,3] in mm (see the module docstring)."""
    return summarize_dtu(dtu_distances(pred, gt, obs, plane, dst, max_dist, seed), scan, num_pred=len(pred))


def dtu_error_cloud_paths(out_dir: str | Path, scan: int) -> list[Path]:
    """``scan{N}_accuracy.ply`` and ``scan{N}_completeness.ply`` in ``out_dir``."""
    return [Path(out_dir) / f"scan{scan}_accuracy.ply", Path(out_dir) / f"scan{scan}_completeness.ply"]


def write_dtu_error_clouds(out_dir: str | Path, scan: int, dist: DTUDistances, scale: float = 2.0,
                           inputs: tuple[str | Path, ...] = ()) -> list[Path]:
    """Write ``scan{N}_accuracy.ply`` (used prediction points) and ``scan{N}_completeness.ply`` (used
    ground-truth points), coloured blue (0 mm) to red (>= ``scale`` mm), with the distance as ``error``
    (never over ``inputs`` or a file that is not an error cloud of this package's)."""

    paths = dtu_error_cloud_paths(out_dir, scan)
    write_error_ply(paths[0], dist.pred[dist.pred_used], dist.pred_dist[dist.pred_used], scale, inputs)
    write_error_ply(paths[1], dist.gt[dist.gt_used], dist.gt_dist[dist.gt_used], scale, inputs)
    return paths


def evaluate_dtu_scan(
    pred_ply: str | Path,
    scan: int,
    dtu_root: str | Path,
    dst: float = DTU_DST,
    max_dist: float = DTU_MAX_DIST,
    seed: int | None = None,
    error_ply_dir: str | Path | None = None,
) -> DTUResult:
    """Evaluate one fused cloud (PLY, DTU world coordinates in mm) with the official files of ``scan``.

    error_ply_dir: also write error-coloured clouds there (:func:`write_dtu_error_clouds`).
    """
    paths = dtu_paths(dtu_root, scan)
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise InputError(f"scan {scan} has no ground truth here: missing {', '.join(missing)}. Pass the folder "
                         "holding the DTU evaluation data (ObsMask/, Points/stl/)", dtu_root)
    obs = load_obs_mask(paths["obs_mask"])
    plane = load_plane(paths["plane"])
    gt = load_cloud(paths["stl"], "ground truth")
    pred = load_cloud(pred_ply, "prediction")
    dist = dtu_distances(pred, gt, obs, plane, dst=dst, max_dist=max_dist, seed=seed)
    result = summarize_dtu(dist, scan, num_pred=len(pred))
    if error_ply_dir is not None:
        write_dtu_error_clouds(error_ply_dir, scan, dist, inputs=(pred_ply, dtu_root))
    return result


def dtu_mean(results: list[DTUResult]) -> dict[str, float]:
    """Unweighted mean over scans of accuracy, completeness and overall (how papers report the table)."""
    if not results:
        raise ValueError("no DTU results to average")
    return {k: float(np.mean([getattr(r, k) for r in results])) for k in ("accuracy", "completeness", "overall")}


def format_dtu_table(results: list[DTUResult]) -> str:
    """A fixed-width per-scan table (mm) with the mean row."""
    lines = [f"{'scan':>6} {'acc':>8} {'comp':>8} {'overall':>8} {'points':>10}"]
    for r in results:
        lines.append(f"{r.scan:>6} {r.accuracy:8.4f} {r.completeness:8.4f} {r.overall:8.4f} {r.num_pred_thinned:>10}")
    if results:
        m = dtu_mean(results)
        lines.append(f"{'mean':>6} {m['accuracy']:8.4f} {m['completeness']:8.4f} {m['overall']:8.4f}")
    return "\n".join(lines)
