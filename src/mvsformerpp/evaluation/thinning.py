"""Reductions of a point cloud: deterministic minimum-spacing thinning (the DTU protocol's ``reducePts_haa``)
and voxel downsampling (Tanks and Temples, ICP).

The official DTU MATLAB evaluation reduces the prediction so that no two kept points are closer
than ``dst`` (0.2 mm): it visits the points in an order, keeps a point unless an earlier kept point
lies within ``dst``, and drops that point's neighbours. MATLAB visits them in ``randperm`` order,
so its numbers change slightly from run to run; here the order is the file order by default, or a
permutation from a seeded generator (``seed``), so a result can always be repeated.
"""

from __future__ import annotations

import numpy as np

from mvsformerpp.evaluation.distances import build_tree
from mvsformerpp.geometry.voxels import voxel_means

#: Points whose neighbourhoods are searched per KD-tree call (bounds memory on dense clouds).
THIN_CHUNK = 1 << 17


def thin_points(points: np.ndarray, min_dist: float, seed: int | None = None, chunk: int = THIN_CHUNK) -> np.ndarray:
    """Greedy thinning to a minimum spacing; returns the [N] bool mask of kept points.

    points: [N,3]; min_dist: two kept points are always more than ``min_dist`` apart, and every
    dropped point has a kept point within ``min_dist`` (distances ``<= min_dist`` count as close,
    as MATLAB's ``rangesearch`` does). seed: None visits points in index order; an int visits them
    in ``np.random.default_rng(seed).permutation`` order.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    keep = np.zeros(n, dtype=bool)
    if n == 0 or min_dist <= 0:
        keep[:] = True
        return keep
    order = np.arange(n) if seed is None else np.random.default_rng(seed).permutation(n)
    tree = build_tree(points)
    removed = bytearray(n)  # byte flags: cheaper than numpy scalar indexing inside the Python loop
    for start in range(0, n, chunk):
        ids = order[start:start + chunk]
        # Skip neighbourhood queries for points an earlier chunk already removed.
        ids = ids[np.frombuffer(bytes(removed), dtype=np.uint8)[ids] == 0]
        neighbours = tree.query_ball_point(points[ids], r=min_dist, workers=-1)
        for i, nb in zip(ids.tolist(), neighbours):
            if removed[i]:
                continue
            keep[i] = True
            for j in nb:
                removed[j] = 1
    return keep


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Open3D-style voxel downsampling: the mean of the points in each occupied voxel.

    The grid starts at ``points.min(0) - voxel/2``; output rows are sorted by voxel index, so the
    result does not depend on the input order. Returns [V,3].
    """
    return voxel_means(points, voxel, origin=points.min(axis=0) - voxel / 2)[0]
