"""``demo``: reconstruct the bundled Middlebury temple (16 views, 640x480) end to end.

The data (``mvsformerpp/data/templeSparseRing``, see its README.txt for the attribution: Seitz,
Diebel, Scharstein, Curless, Szeliski, Middlebury multi-view stereo benchmark) ships with the package.
The depth range is taken from the object's bounding box published in that README.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

# Tight bounding box of the temple model (data/templeSparseRing/README.txt), world units (metres).
TEMPLE_BBOX = (np.array([-0.073568, 0.021728, -0.012445]), np.array([0.028855, 0.181892, 0.062736]))

DEMO_CONFIG = ReconstructConfig(preset="lite", max_size=640, num_views=5, fusion="normal")


def temple_dir() -> Path:
    """Folder of the bundled temple images and ``templeSR_par.txt``."""
    return Path(__file__).resolve().parent.parent / "data" / "templeSparseRing"


def bbox_depth_range(Rs: list[np.ndarray], ts: list[np.ndarray], lo: np.ndarray, hi: np.ndarray,
                     margin: float = 0.1) -> tuple[float, float]:
    """Smallest/largest z-depth of the box corners over all cameras, widened by ``margin`` (relative)."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    z = np.concatenate([(corners @ R.T + t)[:, 2] for R, t in zip(Rs, ts)])
    return float(z.min() * (1 - margin)), float(z.max() * (1 + margin))


def temple_depth_range() -> tuple[float, float]:
    """Depth range of the bundled temple from its bounding box and the cameras in ``templeSR_par.txt``."""
    Rs, ts = [], []
    lines = (temple_dir() / "templeSR_par.txt").read_text().split("\n")[1:]
    for line in lines:
        tok = line.split()
        if len(tok) == 22:
            vals = np.array([float(x) for x in tok[1:]])
            Rs.append(vals[9:18].reshape(3, 3))
            ts.append(vals[18:21])
    return bbox_depth_range(Rs, ts, *TEMPLE_BBOX)


def run_demo(out_dir: str | Path, config: ReconstructConfig = DEMO_CONFIG, quiet: bool = False) -> dict:
    """Reconstruct the bundled temple into ``out_dir``; return the summary."""
    if config.depth_range is None:
        config = dataclasses.replace(config, depth_range=temple_depth_range())
    return reconstruct(temple_dir(), out_dir, config, quiet=quiet)
