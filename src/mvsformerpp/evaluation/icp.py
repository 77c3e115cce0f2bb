"""Rigid ICP refinement of an alignment (point-to-point, closed-form Kabsch updates).

The Tanks-and-Temples toolbox refines its initial (trajectory-based) alignment with Open3D ICP at
several correspondence distances before scoring. This module provides the same kind of refinement
without Open3D: deterministic, point-to-point (the toolbox uses point-to-plane), coarse to fine.
"""

from __future__ import annotations

import numpy as np

from mvsformerpp.evaluation.distances import build_tree


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rigid 4x4 transform minimising sum |R src_i + t - dst_i|^2 (src, dst: [N,3], N >= 3)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - mu_s).T @ (dst - mu_d))
    d = np.sign(np.linalg.det(vt.T @ u.T))  # no reflections
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, mu_d - R @ mu_s
    return T


def icp_refine(
    source: np.ndarray,
    target: np.ndarray,
    init: np.ndarray | None = None,
    max_corr: tuple[float, ...] = (0.05, 0.02, 0.01),
    iterations: int = 30,
    tol: float = 1e-9,
) -> np.ndarray:
    """Refine ``init`` (4x4, default identity) so that ``source`` [N,3] maps onto ``target`` [M,3].

    For each correspondence distance in ``max_corr`` (coarse to fine), up to ``iterations`` rounds
    of: pair every mapped source point with its nearest target point closer than that distance,
    solve the best rigid update in closed form, compose it. Stops a level when the update moves
    points by less than ``tol`` (RMS). Returns the refined 4x4 transform; ``init``'s scale is kept.
    """
    T = np.eye(4) if init is None else np.asarray(init, dtype=np.float64).copy()
    tree = build_tree(target)
    for dist in max_corr:
        for _ in range(iterations):
            moved = source @ T[:3, :3].T + T[:3, 3]
            d, idx = tree.query(moved, k=1, distance_upper_bound=dist, workers=-1)
            ok = np.isfinite(d)
            if ok.sum() < 3:
                break
            delta = kabsch(moved[ok], target[idx[ok]])
            T = delta @ T
            step = moved[ok] @ delta[:3, :3].T + delta[:3, 3] - moved[ok]
            if np.sqrt(np.mean(np.sum(step**2, axis=1))) < tol:
                break
    return T
