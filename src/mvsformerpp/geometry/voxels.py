"""Points grouped by the cubes of a regular grid: how many cubes they occupy and their means per cube."""

from __future__ import annotations

import numpy as np


def _voxel_index(points: np.ndarray, voxel: float, origin: np.ndarray | None) -> np.ndarray:
    if not voxel > 0:
        raise ValueError(f"voxel size must be positive, got {voxel}")
    origin = points.min(axis=0) if origin is None else origin
    return np.floor((points - origin) / voxel).astype(np.int64)


def count_voxels(points: np.ndarray, voxel: float, origin: np.ndarray | None = None) -> int:
    """How many cubes of side ``voxel`` (grid from ``origin``, default the points' minimum) hold a point."""
    return len(np.unique(_voxel_index(points, voxel, origin), axis=0))


def voxel_means(points: np.ndarray, voxel: float, values: np.ndarray | None = None,
                origin: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The mean point [V, 3] (float64) of each occupied cube, and the mean of ``values`` [N, C] there (or
    None); rows sorted by cube index, so the result does not depend on the input order."""
    _, inverse, counts = np.unique(_voxel_index(points, voxel, origin), axis=0, return_inverse=True,
                                   return_counts=True)
    inverse = inverse.ravel()
    both = points if values is None else np.concatenate([points, values], axis=1)
    columns = [both[:, c] for c in range(both.shape[1])]
    sums = np.stack([np.bincount(inverse, weights=col, minlength=len(counts)) for col in columns], axis=1)
    means = sums / counts[:, None]
    return means[:, :3], (None if values is None else means[:, 3:])
