"""Camera frustums for display: the centre and the image corners at a chosen depth."""

from __future__ import annotations

import numpy as np


def frustum_points(K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int, depth: float) -> np.ndarray:
    """World points [5, 3]: the camera centre, then the image corners (0,0), (W,0), (W,H), (0,H) at z = ``depth``."""
    corners = np.array([[0, 0, 1], [width, 0, 1], [width, height, 1], [0, height, 1]], dtype=np.float64)
    cam = (corners @ np.linalg.inv(K).T) * depth
    centre = -R.T @ t
    return np.vstack([centre, (cam - t) @ R])


# Triangles of a frustum mesh over :func:`frustum_points`: four sides and the image rectangle.
FRUSTUM_FACES = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [1, 3, 2], [1, 4, 3]], dtype=np.int64)
