"""View selection: which source views go with each reference view.

The score is the MVSNet / colmap2mvsnet triangulation-angle score (Yao et al., MVSNet, ECCV 2018,
section 4.1): for views i, j and a 3-D point p seen by both, with theta the angle between the
rays p->C_i and p->C_j (degrees),

    G(theta) = exp(-(theta - theta0)^2 / (2 sigma1^2))  if theta <= theta0   (sigma1 = 1)
               exp(-(theta - theta0)^2 / (2 sigma2^2))  otherwise            (sigma2 = 10)

with theta0 = 5 degrees, and the pair score is the sum of G over the points both views see.
Neighbours are the best-scoring views (top 10 by default), best first, views with score 0 left out.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

THETA0_DEG = 5.0
SIGMA1_DEG = 1.0
SIGMA2_DEG = 10.0
# Camera-only selection (no points): pairs seen from further apart than this are not neighbours.
MAX_CAMERA_ANGLE_DEG = 90.0


def triangulation_angle_score(theta_deg: np.ndarray) -> np.ndarray:
    """The piecewise Gaussian G(theta) above, elementwise on angles in degrees."""
    theta = np.asarray(theta_deg, dtype=np.float64)
    sigma = np.where(theta <= THETA0_DEG, SIGMA1_DEG, SIGMA2_DEG)
    return np.exp(-((theta - THETA0_DEG) ** 2) / (2.0 * sigma**2))


def ray_angle_deg(point: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """Angle (degrees) at ``point`` [..., 3] between the rays to camera centres ``c1`` and ``c2``."""
    a = np.asarray(c1, dtype=np.float64) - point
    b = np.asarray(c2, dtype=np.float64) - point
    na = np.linalg.norm(a, axis=-1)
    nb = np.linalg.norm(b, axis=-1)
    cos = np.sum(a * b, axis=-1) / np.maximum(na * nb, 1e-300)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pair_scores_from_points(
    centers: np.ndarray, points: np.ndarray, visibility: list[np.ndarray], cache_bytes: int = 512 << 20
) -> np.ndarray:
    """Score matrix [N, N] (zero diagonal) from shared points.

    ``centers`` [N, 3] camera centres; ``points`` [P, 3]; ``visibility[i]`` the indices of the points
    view i sees. Score(i, j) = sum over points seen by both of G(angle at the point). The unit rays
    point -> camera are cached for all views when they fit in ``cache_bytes``.
    """
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n, p = len(centers), len(points)
    vis = np.zeros((n, p), dtype=bool)
    for i, idx in enumerate(visibility):
        vis[i, np.asarray(idx, dtype=np.int64)] = True

    def rays(i: int, sel: np.ndarray | slice = slice(None)) -> np.ndarray:
        d = centers[i] - points[sel]
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)

    cache = [rays(i) for i in range(n)] if n * p * 24 <= cache_bytes else None
    scores = np.zeros((n, n), dtype=np.float64)
    for i in range(n):
        if not vis[i].any():
            continue
        ui = cache[i] if cache is not None else rays(i)
        for j in range(i + 1, n):
            shared = np.flatnonzero(vis[i] & vis[j])
            if shared.size == 0:
                continue
            uj = cache[j][shared] if cache is not None else rays(j, shared)
            cos = np.einsum("ij,ij->i", ui[shared], uj)
            theta = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
            scores[i, j] = scores[j, i] = float(triangulation_angle_score(theta).sum())
    return scores


def top_neighbors(scores: np.ndarray, k: int = 10) -> list[list[tuple[int, float]]]:
    """Per view, up to ``k`` (index, score) pairs with positive score, best first (ties: lower index)."""
    out = []
    for i, row in enumerate(np.asarray(scores, dtype=np.float64)):
        order = sorted((j for j in range(len(row)) if j != i and row[j] > 0), key=lambda j: (-row[j], j))
        out.append([(j, float(row[j])) for j in order[:k]])
    return out


def point_closest_to_axes(centers: np.ndarray, directions: np.ndarray) -> np.ndarray | None:
    """Least-squares point nearest to all lines ``C_i + s d_i``; None when ill-posed.

    Solves sum_i (I - d_i d_i^T) X = sum_i (I - d_i d_i^T) C_i. Returns None when the axes are
    (nearly) parallel or the point lies behind most cameras (e.g. a forward-facing capture).
    """
    C = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    D = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    D = D / np.linalg.norm(D, axis=1, keepdims=True)
    if len(C) < 2:
        return None
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(C, D):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    w = np.linalg.eigvalsh(A)
    if w[0] < 1e-6 * w[-1] * len(C) or w[0] <= 0:
        return None
    X = np.linalg.solve(A, b)
    in_front = np.sum(np.einsum("ij,ij->i", X - C, D) > 0)
    return X if in_front > len(C) / 2 else None


def neighbors_from_cameras(
    centers: np.ndarray, directions: np.ndarray, k: int = 10
) -> list[list[tuple[int, float]]]:
    """Neighbours when no 3-D points are known (Middlebury, MVSNet folders without pair.txt).

    Heuristic: the scene centre is taken as the point closest to all optical axes
    (:func:`point_closest_to_axes`) and the pair score is G(angle at that point), i.e. the MVSNet
    score with one shared point. When that point is ill-posed (parallel axes), the angle between the
    viewing directions stands in for the triangulation angle. Pairs more than 90 degrees apart are
    not neighbours.
    """
    C = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    D = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    D = D / np.linalg.norm(D, axis=1, keepdims=True)
    n = len(C)
    X = point_closest_to_axes(C, D)
    scores = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            if X is not None:
                theta = ray_angle_deg(X, C[i], C[j])
            else:
                theta = np.degrees(np.arccos(np.clip(D[i] @ D[j], -1.0, 1.0)))
            # Views more than MAX_CAMERA_ANGLE_DEG apart rarely see the same side of a surface.
            if theta <= MAX_CAMERA_ANGLE_DEG:
                scores[i, j] = float(triangulation_angle_score(theta))
    return top_neighbors(scores, k)


def set_neighbors_from_cameras(views: Sequence, k: int = 10) -> None:
    """Give each view (a :class:`~mvsformerpp.io.scene.View`) its ``k`` best neighbours by
    :func:`neighbors_from_cameras` from the views' centres and viewing directions."""
    scored = neighbors_from_cameras(np.stack([v.center for v in views]), np.stack([v.R[2] for v in views]), k)
    for v, nb in zip(views, scored):
        v.neighbors = [j for j, _ in nb]
