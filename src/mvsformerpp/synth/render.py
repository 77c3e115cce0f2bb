"""Procedural multi-view scenes with exact ground truth, and their MVSNet-layout writer.

World frame: z up, ground plane z = 0, objects within about 1 unit of the origin, a back wall
behind them, cameras on an arc at about 4 units looking at the scene. Pixel (x, y) covers
[x, x+1) x [y, y+1): its ray is R^T K^-1 [x + 0.5, y + 0.5, 1] (the fusion convention of
:mod:`mvsformerpp.fusion.core`), and its depth is the z-depth of the first surface hit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mvsformerpp.synth.shapes import Box, Cylinder, Plane, Sphere
from mvsformerpp.synth.textures import albedo

TEXTURES = ("noise", "checker", "stripes", "marble", "flat")
LIGHT = np.array([0.4, -0.5, 0.77]) / np.linalg.norm([0.4, -0.5, 0.77])


@dataclass
class Surface:
    shape: object
    texture: str
    colors: np.ndarray  # [2, 3]
    seed: int
    scale: float = 1.0


@dataclass
class Camera:
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t


@dataclass
class SynthScene:
    surfaces: list[Surface]
    cameras: list[Camera]
    width: int
    height: int
    meta: dict = field(default_factory=dict)


def look_at(center: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at ``center`` looking at ``target`` (x right, y down, z forward)."""
    f = target - center
    f = f / np.linalg.norm(f)
    r = np.cross(f, np.asarray(up))
    r = r / np.linalg.norm(r)
    down = np.cross(f, r)
    R = np.stack([r, down, f])
    return R, -R @ center


def random_scene(seed: int, num_views: int = 7, height: int = 256, width: int = 320,
                 num_objects: int | None = None, arc_degrees: float = 50.0) -> SynthScene:
    """A random scene: several objects of different shapes, sizes, depths and textures on a ground
    plane before a wall, seen by ``num_views`` cameras spread over ``arc_degrees`` on an arc."""
    rng = np.random.default_rng(seed)
    pal = lambda: rng.uniform(0.05, 0.95, size=(2, 3))  # noqa: E731
    surfaces = [
        Surface(Plane(np.array([0, 0, 1.0]), 0.0), "checker" if rng.random() < 0.5 else "noise", pal(), seed + 1, 0.7),
        Surface(Plane(np.array([1.0, 0, 0]), -2.2), "noise", pal(), seed + 2, 0.6),  # back wall x = -2.2
    ]
    n_obj = num_objects if num_objects is not None else int(rng.integers(3, 7))
    for k in range(n_obj):
        kind = ("sphere", "box", "cylinder")[k % 3] if k < 3 else rng.choice(["sphere", "box", "cylinder"])
        x, y = rng.uniform(-1.2, 0.9), rng.uniform(-1.1, 1.1)
        size = rng.uniform(0.18, 0.45)
        if kind == "sphere":
            shape = Sphere(np.array([x, y, size + rng.uniform(0, 0.4)]), size)
        elif kind == "box":
            half = np.array([size, size * rng.uniform(0.6, 1.4), size * rng.uniform(0.6, 1.6)])
            shape = Box(np.array([x, y, half[2]]), half, rng.uniform(0, np.pi))
        else:
            shape = Cylinder(np.array([x, y]), size * 0.8, 0.0, size * rng.uniform(1.5, 3.0))
        tex = TEXTURES[(k + seed) % len(TEXTURES)]
        surfaces.append(Surface(shape, tex, pal(), seed + 10 + k, rng.uniform(0.7, 1.6)))
    focal = 0.95 * width
    K = np.array([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1.0]])
    target = np.array([-0.2, 0.0, 0.35])
    radius, elevation = rng.uniform(3.6, 4.4), np.deg2rad(rng.uniform(18, 28))
    cams = []
    for i in range(num_views):
        az = np.deg2rad(-arc_degrees / 2 + arc_degrees * i / max(num_views - 1, 1))
        c = target + radius * np.array([np.cos(elevation) * np.cos(az), np.cos(elevation) * np.sin(az),
                                        np.sin(elevation)])
        R, t = look_at(c, target)
        cams.append(Camera(K.copy(), R, t))
    return SynthScene(surfaces, cams, width, height, {"seed": seed})


def cast(scene: SynthScene, origins: np.ndarray, dirs: np.ndarray):
    """First hit of rays: (t [N], surface index [N] (-1 = miss), normal [N,3])."""
    best_t = np.full(len(dirs), np.inf)
    best_s = np.full(len(dirs), -1)
    best_n = np.zeros_like(dirs)
    for i, surf in enumerate(scene.surfaces):
        t, n = surf.shape.intersect(origins, dirs)
        closer = t < best_t
        best_t = np.where(closer, t, best_t)
        best_s = np.where(closer, i, best_s)
        best_n = np.where(closer[:, None], n, best_n)
    return best_t, best_s, best_n


def shade(scene: SynthScene, points: np.ndarray, surf: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Lambertian colour [N,3] in [0,1] under one fixed light: the same in every view."""
    rgb = np.zeros_like(points)
    for i, s in enumerate(scene.surfaces):
        m = surf == i
        if m.any():
            rgb[m] = albedo(s.texture, points[m], s.colors, s.seed, s.scale)
    lam = np.abs(normals @ LIGHT)  # two-sided
    return np.clip(rgb * (0.35 + 0.65 * lam)[:, None], 0, 1)


def render_view(scene: SynthScene, cam: Camera):
    """(image uint8 [H,W,3], depth float32 [H,W] (0 = nothing hit), world points [H,W,3])."""
    H, W = scene.height, scene.width
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    pix = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5, np.ones(H * W)], axis=1)
    dirs = pix @ np.linalg.inv(cam.K).T @ cam.R  # rows: R^T K^-1 p, so t = z-depth
    origins = np.broadcast_to(cam.center, dirs.shape)
    t, surf, normals = cast(scene, origins, dirs)
    hit = np.isfinite(t)
    pts = origins + np.where(hit, t, 0)[:, None] * dirs
    rgb = np.zeros_like(pts)
    rgb[hit] = shade(scene, pts[hit], surf[hit], normals[hit])
    image = np.round(rgb * 255).astype(np.uint8).reshape(H, W, 3)
    depth = np.where(hit, t, 0).astype(np.float32).reshape(H, W)
    return image, depth, pts.reshape(H, W, 3)
