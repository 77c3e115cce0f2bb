"""Structure-from-motion outcome of a COLMAP sparse model, as plain data (the report's SfM section)."""

from __future__ import annotations

from typing import Any

import numpy as np

from mvsformerpp.io.colmap_model import CAMERA_MODELS, ColmapModel


def model_statistics(model: ColmapModel, photos: list[str] | None = None) -> dict[str, Any]:
    """Registered photos, dropped ones (``photos`` not in the model), points, observations and intrinsics.

    ``mean_reprojection_error`` is the mean of the points' errors (pixels), COLMAP's own statistic;
    ``cameras`` lists each camera's model, size and named parameters.
    """
    registered = sorted(im.name for im in model.images.values())
    errors = np.array([p.error for p in model.points3D.values()], dtype=np.float64)
    tracks = np.array([len(p.image_ids) for p in model.points3D.values()], dtype=np.float64)
    stats: dict[str, Any] = {
        "registered": len(registered),
        "registered_names": registered,
        "points": len(model.points3D),
        "observations": int(tracks.sum()),
        "mean_track_length": float(tracks.mean()) if tracks.size else None,
        "mean_reprojection_error": float(errors.mean()) if errors.size else None,
        "cameras": [
            {"id": c.id, "model": c.model, "width": c.width, "height": c.height,
             "params": dict(zip(CAMERA_MODELS[c.model][1], (float(x) for x in c.params)))}
            for c in sorted(model.cameras.values(), key=lambda c: c.id)
        ],
    }
    if photos is not None:
        reg = set(registered)
        stats["photos"] = len(photos)
        stats["dropped"] = [p for p in photos if p not in reg]
    return stats
