"""Large synthetic scenes in seconds: a strip of cameras over a textured tilted plane.

For benchmarks and tests that need many views (fusion memory, sharded reconstruction) rather than
varied geometry: cameras with identity rotation at ``x = i * baseline`` look down +z at the plane
``z = depth + slope * x``, so every pixel's depth has a closed form and neighbouring views overlap.
With ``with_depth_maps`` the exact depth maps and a confidence map are written as ``depth_est/`` and
``confidence/``, the layout ``mvsformerpp fuse`` reads.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from mvsformerpp.io.mvsnet import MVSNetCam, write_cam, write_pair
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.utils.atomic import atomic_open


def strip_depth(K: np.ndarray, center_x: float, height: int, width: int, depth: float, slope: float) -> np.ndarray:
    """Depth of every pixel centre of a camera at ``(center_x, 0, 0)`` (identity rotation) on the plane."""
    rx = ((np.arange(width) + 0.5 - K[0, 2]) / K[0, 0])[None, :].repeat(height, 0)
    # Camera ray (rx, ry, 1) from (cx, 0, 0): z = depth + slope * (cx + z * rx)  =>  z (1 - slope rx) = ...
    return ((depth + slope * center_x) / (1.0 - slope * rx)).astype(np.float32)


def generate_strip_scene(out_dir: str | Path, num_views: int = 16, height: int = 240, width: int = 320,
                         seed: int = 0, with_depth_maps: bool = True, num_neighbors: int = 10,
                         depth: float = 10.0, slope: float = 0.05) -> Path:
    """Write ``images/``, ``cams/``, ``pair.txt`` (and ``depth_est/``, ``confidence/``) of a strip scene."""
    out = Path(out_dir)
    rng = np.random.default_rng(seed)
    K = np.array([[width, 0, width / 2], [0, width, height / 2], [0, 0, 1]], dtype=np.float64)
    baseline = 0.05 * depth  # a twentieth of the view width on the plane: neighbours overlap widely
    centers = np.arange(num_views) * baseline
    # One texture along the whole strip, sampled at each view's footprint on the plane.
    span = int(np.ceil((centers[-1] / depth * width) + 2 * width))
    texture = rng.integers(0, 256, (height, span, 3), dtype=np.uint8)
    pairs = {}
    for i, cx in enumerate(centers):
        stem = f"{i:08d}"
        d = strip_depth(K, cx, height, width, depth, slope)
        x0 = int(round(cx / depth * width))
        with atomic_open(out / "images" / f"{stem}.png", "wb") as f:
            Image.fromarray(texture[:, x0:x0 + width]).save(f, format="PNG", compress_level=1)
        E = np.eye(4)
        E[0, 3] = -cx
        lo, hi = float(d.min()) * 0.9, float(d.max()) * 1.1
        write_cam(out / "cams" / f"{stem}_cam.txt", MVSNetCam(E, K, lo, hi, (hi - lo) / 191, 192))
        order = sorted((j for j in range(num_views) if j != i), key=lambda j: (abs(j - i), j))[:num_neighbors]
        pairs[i] = [(j, 1.0 / abs(j - i)) for j in order]
        if with_depth_maps:
            write_pfm(out / "depth_est" / f"{stem}.pfm", d)
            y, x = np.mgrid[:height, :width] / width  # a smooth field, as a network's confidence is
            conf = (0.6 + 0.4 * np.sin(9 * x + i) * np.cos(7 * y - i)).astype(np.float32)
            write_pfm(out / "confidence" / f"{stem}.pfm", conf)
    write_pair(out / "pair.txt", pairs)
    return out
