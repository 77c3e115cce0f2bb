"""Per-view fingerprints: a depth map is reused on resume only if nothing it depends on has changed.

A depth map of reference view ``i`` depends on the settings that change results (network preset,
resolution, views per map, hypotheses, temperatures, precision, seed), the weights file, and for
the reference and each of its source views: the camera (size, K, R, t), the photo, and the reference's
depth range. :func:`view_fingerprints` hashes exactly those, so editing one depth line or one line
of ``pair.txt`` recomputes the views it affects and no other, and a different scene written into the
same folder never reuses a map even when its ``config.json`` is gone.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from mvsformerpp.inference.runner import select_sources
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.utils.files import file_identity


def _camera(view: View) -> list:
    return [view.name, view.width, view.height,
            *(np.asarray(a, dtype=np.float64).round(9).ravel().tolist() for a in (view.K, view.R, view.t))]


def view_fingerprints(scene: Scene, num_views: int, settings: dict, weights: str | None) -> list[str]:
    """One hash per view of ``scene`` over everything its depth map depends on (see the module docstring)."""
    images = [file_identity(v.image_path) for v in scene.views]
    base = json.dumps({"settings": settings, "weights": weights}, sort_keys=True, default=str)
    keys = []
    for i, view in enumerate(scene.views):
        ids = [i] + select_sources(scene, i, num_views)
        payload = {"base": base, "depth_range": [view.depth_min, view.depth_max],
                   "views": [_camera(scene.views[j]) + [images[j]] for j in ids]}
        keys.append(hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:20])
    return keys
