"""The in-memory scene: the one currency between readers, inference, fusion and evaluation.

Conventions (written once, used everywhere):
* ``K`` is the 3x3 pinhole intrinsic matrix for the image at ``(width, height)`` pixels, as the
  source format gives it; :mod:`mvsformerpp.geometry` says which pixel convention each computation
  uses (integer pixel coordinates for cost-volume warping, pixel centres for fusion).
* ``R``, ``t`` map world to camera: X_cam = R @ X_world + t.
* ``depth_min``/``depth_max`` bound the z-depth (camera frame) of the scene seen by the view.
* ``neighbors`` are indices into ``Scene.views``, best first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError


@dataclass
class View:
    """One calibrated image."""

    name: str
    image_path: Path
    width: int
    height: int
    K: np.ndarray  # [3,3] float64
    R: np.ndarray  # [3,3] float64, world -> camera
    t: np.ndarray  # [3] float64, world -> camera
    depth_min: float | None = None
    depth_max: float | None = None
    neighbors: list[int] = field(default_factory=list)
    depth_gt_path: Path | None = None  # ground-truth depth (PFM or similar), where the layout has it
    mask_path: Path | None = None  # ground-truth validity mask, where the layout has it

    def __post_init__(self) -> None:
        self.image_path = Path(self.image_path)
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        self.width, self.height = int(self.width), int(self.height)
        self.neighbors = [int(i) for i in self.neighbors]

    @property
    def extrinsic(self) -> np.ndarray:
        """4x4 world-to-camera matrix."""
        E = np.eye(4)
        E[:3, :3] = self.R
        E[:3, 3] = self.t
        return E

    @property
    def projection(self) -> np.ndarray:
        """3x4 matrix K [R | t]."""
        return self.K @ self.extrinsic[:3]

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return -self.R.T @ self.t


MIN_FIELD_OF_VIEW = 0.01
"""Degrees: narrower than any lens (a 2000 mm telephoto sees about 1 degree); a wrong focal length."""
MAX_FIELD_OF_VIEW = 170.0
"""Degrees: wider than a pinhole camera's photo can be (the projection diverges at 180); a wrong focal length."""
DEPTH_LIMITS = (1e-12, 1e12)
"""Depths (and a depth range's ends) the network computes with in single precision, inverses and products
included; beyond them they round to 0 or overflow."""
MAX_CENTRE_RATIO = 1e5
"""Largest distance of a camera centre from the origin, in units of the camera's far depth: farther, the
single-precision world coordinates of the scene's points are coarser than about a percent of their depth."""


def check_depth_range(near: float, far: float, what: str, where: Path | None = None) -> None:
    """Refuse a depth range outside :data:`DEPTH_LIMITS` (it must already satisfy 0 < near < far)."""
    lo, hi = DEPTH_LIMITS
    if not (lo <= near and far <= hi):
        raise InputError(f"{what} {near:g}..{far:g} must lie within {lo:g}..{hi:g}: the network computes depths and "
                         "their inverses in single precision, where values beyond round to 0 or overflow (give the "
                         "scene in other units?)", where)


@dataclass
class Scene:
    """A set of calibrated views with depth ranges and neighbour lists."""

    views: list[View]
    root: Path | None = None
    source_format: str = "unknown"

    def __len__(self) -> int:
        return len(self.views)

    def validate(self, require_depth_range: bool = True) -> Scene:
        """Check the scene is usable for MVS; raise :class:`InputError` naming the problem."""
        where = self.root
        if not self.views:
            raise InputError("the scene has no views", where)
        n = len(self.views)
        for i, v in enumerate(self.views):
            label = f"view {i} ({v.name})"
            for name, arr in (("K", v.K), ("R", v.R), ("t", v.t)):
                if not np.all(np.isfinite(arr)):
                    raise InputError(f"{label}: camera {name} has non-finite values", where)
            if v.width <= 0 or v.height <= 0:
                raise InputError(f"{label}: image size {v.width}x{v.height} is not positive", where)
            if abs(np.linalg.det(v.R) - 1.0) > 1e-3:
                raise InputError(f"{label}: R is not a rotation (det = {np.linalg.det(v.R):.4f})", where)
            if v.K[0, 0] <= 0 or v.K[1, 1] <= 0:
                raise InputError(f"{label}: focal lengths must be positive (K = {v.K.tolist()})", where)
            fov = np.degrees(2 * np.arctan(max(v.width, v.height) / 2 / max(v.K[0, 0], v.K[1, 1])))
            if fov < MIN_FIELD_OF_VIEW:
                raise InputError(f"{label}: a focal length of {max(v.K[0, 0], v.K[1, 1]):.6g} px for a {v.width}x"
                                 f"{v.height} photo is a field of view of {fov:.3g} degrees (below "
                                 f"{MIN_FIELD_OF_VIEW} degrees): the intrinsics are wrong (units? scale?)", where)
            fov = np.degrees(2 * np.arctan(max(v.width, v.height) / 2 / min(v.K[0, 0], v.K[1, 1])))
            if fov > MAX_FIELD_OF_VIEW:
                raise InputError(f"{label}: a focal length of {min(v.K[0, 0], v.K[1, 1]):.6g} px for a {v.width}x"
                                 f"{v.height} photo is a field of view of {fov:.4g} degrees (above "
                                 f"{MAX_FIELD_OF_VIEW:g}, wider than a pinhole photo can be): the intrinsics are wrong "
                                 "(units? scale?)", where)
            bad = [j for j in v.neighbors if not 0 <= j < n or j == i]
            if bad:
                raise InputError(f"{label}: neighbour indices {bad} are not other views of the scene", where)
            if require_depth_range:
                if v.depth_min is None or v.depth_max is None:
                    raise InputError(f"{label}: no depth range (give one with --depth-range)", where)
                if not (np.isfinite(v.depth_min) and np.isfinite(v.depth_max)):
                    raise InputError(f"{label}: depth range {v.depth_min}..{v.depth_max} is not finite", where)
                if not 0 < v.depth_min < v.depth_max:
                    raise InputError(
                        f"{label}: depth range {v.depth_min}..{v.depth_max} must satisfy 0 < min < max", where
                    )
                check_depth_range(v.depth_min, v.depth_max, f"{label}: depth range", where)
            far = v.depth_max if v.depth_max is not None and 0 < v.depth_max < np.inf else None
            centre = float(np.linalg.norm(v.center))
            if centre > (MAX_CENTRE_RATIO * far if far else DEPTH_LIMITS[1]):
                limit = f"{MAX_CENTRE_RATIO:g} times its far depth {far:g}" if far else f"{DEPTH_LIMITS[1]:g}"
                raise InputError(f"{label}: the camera centre lies {centre:.3g} from the origin, more than {limit}: in "
                                 "single precision the scene's points would be placed no finer than about a percent "
                                 "of their depth. Move the origin into the scene (subtract one offset from every "
                                 "camera position)", where)
        return self
