"""ICP refinement of an alignment as the Tanks-and-Temples toolbox does it, without Open3D.

The toolbox (``python_toolbox/evaluation/run.py``, Knapitsch et al. 2017) refines its initial alignment
in three rounds of point-to-point ICP that also estimates a scale (Open3D's
``TransformationEstimationPointToPoint(with_scaling=True)``, i.e. Umeyama's closed-form similarity),
each on the cropped clouds, at most 20 iterations, stopping when fitness and inlier RMSE change by less
than 1e-6 (``ICPConvergenceCriteria(1e-6, 20)``):

1. both clouds voxel-downsampled to ``tau``, correspondences closer than ``80 tau``;
2. voxel ``tau / 2``, correspondences closer than ``20 tau``;
3. no voxel downsampling (uniform subsampling above 4 million points), correspondences closer than
   ``2 tau``.

Each round starts from the previous round's transform. :data:`TOOLBOX_SCHEDULE` holds these rounds in
units of ``tau``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mvsformerpp.evaluation.distances import build_tree
from mvsformerpp.evaluation.thinning import voxel_downsample

MAX_POINTS = 4_000_000
"""Above this many points a cloud is subsampled uniformly (every k-th point) in the last round."""


@dataclass(frozen=True)
class IcpRound:
    """One round of the refinement, in units of the evaluation threshold tau."""

    voxel: float | None
    """Voxel size of the downsampling (None: uniform subsampling above MAX_POINTS only)."""
    max_corr: float
    """Largest correspondence distance."""
    iterations: int = 20
    """Iteration cap."""


TOOLBOX_SCHEDULE = (IcpRound(1.0, 80.0), IcpRound(0.5, 20.0), IcpRound(None, 2.0))


def similarity(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> np.ndarray:
    """The 4x4 ``[sR | t]`` minimising sum |s R src_i + t - dst_i|^2 (Umeyama 1991; s = 1 when not
    ``with_scale``, the Kabsch solution). src, dst: [N,3], N >= 3."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    u, sig, vt = np.linalg.svd(b.T @ a / len(src))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])  # no reflections
    R = u @ S @ vt
    scale = float(np.trace(np.diag(sig) @ S) / np.mean(np.sum(a**2, axis=1))) if with_scale else 1.0
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = scale * R, mu_d - scale * R @ mu_s
    return T


def icp(source: np.ndarray, target: np.ndarray, max_corr: float, iterations: int = 20,
        with_scale: bool = True, tol: float = 1e-6) -> np.ndarray:
    """Point-to-point ICP from the identity: the 4x4 transform mapping ``source`` onto ``target``.

    Each iteration pairs every (moved) source point with its nearest target point closer than
    ``max_corr`` and composes the closed-form :func:`similarity` of the pairs; it stops after
    ``iterations`` or when the fitness (share of source points paired) and the inlier RMSE both change
    by less than ``tol``.
    """
    tree = build_tree(target)
    T = np.eye(4)
    moved = source

    def pairs(points):
        d, idx = tree.query(points, k=1, distance_upper_bound=max_corr, workers=-1)
        ok = np.isfinite(d)
        rmse = float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else 0.0
        return ok, idx, float(ok.mean()) if len(points) else 0.0, rmse

    ok, idx, fitness, rmse = pairs(moved)
    for _ in range(iterations):
        if ok.sum() < 3:
            break
        update = similarity(moved[ok], target[idx[ok]], with_scale)
        T = update @ T
        moved = source @ T[:3, :3].T + T[:3, 3]
        ok, idx, new_fitness, new_rmse = pairs(moved)
        converged = abs(new_fitness - fitness) < tol and abs(new_rmse - rmse) < tol
        fitness, rmse = new_fitness, new_rmse
        if converged:
            break
    return T


def _uniform(points: np.ndarray) -> np.ndarray:
    return points[:: int(round(len(points) / MAX_POINTS))] if len(points) > MAX_POINTS else points


def icp_refine(source: np.ndarray, target: np.ndarray, tau: float, init: np.ndarray | None = None,
               schedule: tuple[IcpRound, ...] = TOOLBOX_SCHEDULE,
               crop: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Refine ``init`` (4x4, default identity) so that ``source`` [N,3] maps onto ``target`` [M,3].

    Runs the rounds of ``schedule`` (distances in units of ``tau``), each on the source moved by the
    transform so far and the target, both cropped by ``crop`` (a boolean mask function) when given and
    downsampled as the round says (:func:`mvsformerpp.evaluation.thinning.voxel_downsample`). Returns the
    refined 4x4 similarity transform.
    """
    T = np.eye(4) if init is None else np.asarray(init, dtype=np.float64).copy()
    for rnd in schedule:
        moved = source @ T[:3, :3].T + T[:3, 3]
        s, t = (moved, target) if crop is None else (moved[crop(moved)], target[crop(target)])
        if len(s) < 3 or len(t) < 3:
            break
        if rnd.voxel is None:
            s, t = _uniform(s), _uniform(t)
        else:
            s, t = voxel_downsample(s, rnd.voxel * tau), voxel_downsample(t, rnd.voxel * tau)
        T = icp(s, t, rnd.max_corr * tau, rnd.iterations) @ T
    return T
