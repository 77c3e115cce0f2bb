"""Procedural multi-view scenes with exact ground truth, and their MVSNet-layout writer.

World frame: z up, ground plane z = 0, objects within about 1 unit of the origin, a back wall
behind them, cameras on an arc at about 4 units looking at the scene. Pixel (x, y) covers
[x, x+1) x [y, y+1): its ray is R^T K^-1 [x + 0.5, y + 0.5, 1] (the fusion convention of
:mod:`mvsformerpp.fusion.core`), and its depth is the z-depth of the first surface hit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from mvsformerpp.synth.mipmaps import LEVELS
from mvsformerpp.synth.photos import sample_texture
from mvsformerpp.synth.shapes import may_hit
from mvsformerpp.synth.textures import albedo, fractal_noise

TEXTURES = ("noise", "checker", "stripes", "marble", "flat")
LIGHT = np.array([0.4, -0.5, 0.77]) / np.linalg.norm([0.4, -0.5, 0.77])


@dataclass
class Surface:
    shape: object
    texture: str
    """A solid texture of :func:`albedo` (``noise``, ``checker``, ...) or ``photo`` (an image texture)."""
    colors: np.ndarray  # [2, 3]
    seed: int
    scale: float = 1.0
    photo: int = 0
    """``photo`` textures: index into the texture set (modulo its size)."""
    texels_per_unit: float = 100.0
    """``photo`` textures: texels of the finest level per world unit."""
    frame: np.ndarray | None = None
    """``photo`` textures: 3x3 rotation whose columns are the texture-projection axes (None = world axes)."""
    specular: float = 0.0
    """Strength of the view-dependent highlight (0 = matte); glossy surfaces break photo-consistency."""
    shininess: float = 30.0


@dataclass
class Camera:
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    gain: np.ndarray | None = None
    """Per-channel exposure x white balance of this view (None = 1)."""
    blur: float = 0.0
    """Gaussian blur sigma in pixels (defocus, motion)."""
    noise: float = 0.0
    """Sensor-noise standard deviation (in [0, 1] intensity units)."""
    noise_seed: int = 0
    sensor: tuple[np.ndarray, int, int] | None = None
    """(K, width, height) of the whole photo this view is a window of (None: the view is the whole photo).

    ``K`` above is the window's intrinsics (the photo's with the principal point moved by the window's
    offset); the photo's pixels share the window's pose, so z-depth is the same in both."""

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t


@dataclass
class Sky:
    """What rays that hit nothing see outdoors: a sky at infinity, a function of the ray's direction only,
    so every view sees it alike (no parallax, as real sky and far background) while its depth stays
    unknown (0, never supervised): a gradient from the horizon to the zenith and soft clouds."""

    horizon: np.ndarray
    zenith: np.ndarray
    clouds: float = 0.0
    """Cloud cover strength in [0, 1]."""
    seed: int = 0

    def colour(self, dirs: np.ndarray) -> np.ndarray:
        """RGB [N,3] of rays [N,3] (any length)."""
        d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        up = np.sqrt(np.clip(d[:, 2], 0, 1))[:, None]
        rgb = self.horizon * (1 - up) + self.zenith * up
        if self.clouds > 0:
            cover = (np.clip((fractal_noise(d, self.seed, octaves=4, base_freq=3.0) - 0.5) * 4, 0, 1) * self.clouds)
            rgb = rgb * (1 - cover[:, None]) + 0.92 * cover[:, None]
        return rgb


@dataclass
class SynthScene:
    surfaces: list[Surface]
    cameras: list[Camera]
    width: int
    height: int
    meta: dict = field(default_factory=dict)
    light: np.ndarray = field(default_factory=lambda: LIGHT.copy())
    """Unit direction towards the (directional) light, fixed in the world."""
    ambient: float = 0.35
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """Colour of rays that hit nothing (their depth is 0: invalid), where the scene has no :attr:`sky`."""
    sky: Sky | None = None
    """Outdoor scenes: what rays that hit nothing see (depth 0 all the same)."""
    supersample: int = 1
    """Colour samples per pixel side (2 = 4 rays per pixel, anti-aliased); depth is always at the centre."""
    textures: tuple = ()
    """Mip pyramids that ``photo`` surfaces index (see :mod:`mvsformerpp.synth.photos`)."""
    detail: float = 0.0
    """Strength of the fine surface detail (0 = none; see :func:`detail_factor`): grain that goes on below
    the scale of a surface's own texture, as real materials have, so a view that magnifies a texture (a
    window of a high-resolution photo) still has matchable structure at the pixel scale."""


def look_at(center: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at ``center`` looking at ``target`` (x right, y down, z forward)."""
    f = target - center
    f = f / np.linalg.norm(f)
    r = np.cross(f, np.asarray(up))
    r = r / np.linalg.norm(r)
    down = np.cross(f, r)
    R = np.stack([r, down, f])
    return R, -R @ center


def cast(scene: SynthScene, origins: np.ndarray, dirs: np.ndarray):
    """First hit of rays: (t [N], surface index [N] (-1 = miss), normal [N,3]).

    Finite shapes are only intersected with the rays that pass their bounding sphere, and normals
    are computed once, for the winning surface of each ray.
    """
    origins = np.broadcast_to(origins, dirs.shape)
    best_t = np.full(len(dirs), np.inf)
    best_s = np.full(len(dirs), -1)
    for i, surf in enumerate(scene.surfaces):
        rays = np.flatnonzero(may_hit(surf.shape, origins, dirs))
        if len(rays) == 0:
            continue
        t, _ = surf.shape.intersect(origins[rays], dirs[rays])
        closer = t < best_t[rays]
        best_t[rays[closer]] = t[closer]
        best_s[rays[closer]] = i
    best_n = np.zeros_like(dirs)
    for i in np.unique(best_s[best_s >= 0]):
        rays = np.flatnonzero(best_s == i)
        _, n = scene.surfaces[i].shape.intersect(origins[rays], dirs[rays])
        best_n[rays] = n
    return best_t, best_s, best_n


def _photo_albedo(scene: SynthScene, s: Surface, p: np.ndarray, n: np.ndarray, footprint: np.ndarray):
    """Image texture projected along the dominant axis of the normal in the surface's texture frame."""
    frame = np.eye(3) if s.frame is None else s.frame
    q, nl = p @ frame, np.abs(n @ frame)
    axis = nl.argmax(1)
    first = np.where(axis == 0, 1, 0)
    second = np.where(axis == 2, 1, 2)
    rows = np.arange(len(p))
    uv = np.stack([q[rows, first], q[rows, second]], 1) * s.texels_per_unit
    uv = uv + np.array([37.0, 53.0]) * (s.seed % 97)  # a different crop of the photo per surface
    levels = scene.textures[s.photo % len(scene.textures)]
    tilt = np.maximum(nl[rows, axis], 0.3)
    rgb = sample_texture(levels, uv, footprint * s.texels_per_unit / tilt)
    return rgb * s.colors[1] + s.colors[0] * (1 - s.colors[1])  # tint, keeping the photo's structure


DETAIL_DENSITY = 8.0
"""Texels of the detail layer per texel of the surface's own texture (three octaves finer)."""


def detail_factor(scene: SynthScene, s: Surface, p: np.ndarray, n: np.ndarray, footprint: np.ndarray) -> np.ndarray:
    """Multiplicative albedo detail [N] of surface ``s``: the luminance of another photo of the texture set,
    mapped on the surface like a photo texture at :data:`DETAIL_DENSITY` times the surface's texture
    density, with a per-surface strength up to ``scene.detail`` (a tenth of it on ``flat`` surfaces, which
    stay nearly textureless). The mip pyramid filters it where it is finer than a pixel, and it fades out
    where even its coarsest level would alias, so it never adds noise that differs between views."""
    rng = np.random.default_rng([s.seed, 7])
    strength = scene.detail * rng.uniform(0.5, 1.0) * (0.1 if s.texture == "flat" else 1.0)
    density = DETAIL_DENSITY * (s.texels_per_unit if s.texture == "photo" else 384.0 * s.scale)
    frame = np.eye(3) if s.frame is None else s.frame
    q, nl = p @ frame, np.abs(n @ frame)
    axis = nl.argmax(1)
    rows = np.arange(len(p))
    uv = np.stack([q[rows, np.where(axis == 0, 1, 0)], q[rows, np.where(axis == 2, 1, 2)]], 1) * density
    uv = uv + rng.uniform(0, 4096, 2)
    fp = footprint * density / np.maximum(nl[rows, axis], 0.3)
    levels = scene.textures[int(rng.integers(1 << 16)) % len(scene.textures)]
    lum = sample_texture(levels, uv, fp).mean(1)
    mean = float(levels[-1].mean()) / 255.0
    fade = np.clip(LEVELS - np.log2(np.maximum(fp, 1e-6)), 0.0, 1.0)
    return np.clip(1.0 + 2.0 * strength * fade * (lum - mean), 0.0, 2.0)


def shade(scene: SynthScene, points: np.ndarray, surf: np.ndarray, normals: np.ndarray,
          view_dirs: np.ndarray | None = None, footprint: np.ndarray | None = None) -> np.ndarray:
    """Colour [N,3] in [0,1]: albedo x (ambient + Lambert) under the scene's fixed light, plus a
    Blinn-Phong highlight on glossy surfaces (view-dependent: needs ``view_dirs``, unit, towards the
    camera). ``footprint``: world size of one pixel at each point (for texture filtering)."""
    rgb = np.zeros_like(points)
    spec = np.zeros(len(points))
    for i, s in enumerate(scene.surfaces):
        m = surf == i
        if not m.any():
            continue
        if s.texture == "photo":
            fp = footprint[m] if footprint is not None else np.ones(int(m.sum()))
            rgb[m] = _photo_albedo(scene, s, points[m], normals[m], fp)
        else:
            rgb[m] = albedo(s.texture, points[m], s.colors, s.seed, s.scale)
        if scene.detail > 0 and scene.textures:
            fp = footprint[m] if footprint is not None else np.ones(int(m.sum()))
            rgb[m] *= detail_factor(scene, s, points[m], normals[m], fp)[:, None]
        if s.specular > 0 and view_dirs is not None:
            nrm = normals[m] * np.sign(np.einsum("ij,ij->i", normals[m], view_dirs[m]))[:, None]  # face the viewer
            half = view_dirs[m] + scene.light
            half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
            spec[m] = s.specular * np.clip(np.einsum("ij,ij->i", nrm, half), 0, 1) ** s.shininess
    lam = np.abs(normals @ scene.light)  # two-sided
    return np.clip(rgb * (scene.ambient + (1 - scene.ambient) * lam)[:, None] + spec[:, None], 0, 1)


def _pixel_rays(cam: Camera, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    pix = np.stack([xs, ys, np.ones_like(xs)], axis=1)
    return pix @ np.linalg.inv(cam.K).T @ cam.R  # rows: R^T K^-1 p, so t = z-depth


def _colour(scene: SynthScene, cam: Camera, dirs: np.ndarray, t: np.ndarray, surf: np.ndarray,
            normals: np.ndarray) -> np.ndarray:
    hit = np.isfinite(t)
    pts = cam.center + np.where(hit, t, 0)[:, None] * dirs
    rgb = np.broadcast_to(scene.background, pts.shape).copy()
    if scene.sky is not None and not hit.all():
        rgb[~hit] = scene.sky.colour(dirs[~hit])
    if hit.any():
        to_cam = cam.center - pts[hit]
        dist = np.linalg.norm(to_cam, axis=1, keepdims=True)
        footprint = t[hit] / cam.K[0, 0]
        rgb[hit] = shade(scene, pts[hit], surf[hit], normals[hit], to_cam / np.maximum(dist, 1e-12), footprint)
    return rgb


def _camera_effects(image: np.ndarray, cam: Camera) -> np.ndarray:
    """Exposure and white balance, blur, then sensor noise: what differs between photos of one scene."""
    if cam.gain is not None:
        image = image * cam.gain
    if cam.blur > 0:
        from scipy.ndimage import gaussian_filter

        image = gaussian_filter(image, sigma=(cam.blur, cam.blur, 0), mode="nearest")
    if cam.noise > 0:
        image = image + np.random.default_rng(cam.noise_seed).normal(0, cam.noise, image.shape)
    return np.clip(image, 0, 1)


def _sensor_rays(scene: SynthScene, cam: Camera, grid: tuple[int, int]):
    """(ray lengths to the first hit (z-depths, inf = miss), directions) of a sparse grid over the photo."""
    K, width, height = cam.sensor
    ys, xs = np.meshgrid((np.arange(grid[0]) + 0.5) * height / grid[0], (np.arange(grid[1]) + 0.5) * width / grid[1],
                         indexing="ij")
    pix = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1)
    dirs = pix @ np.linalg.inv(K).T @ cam.R
    t, _, _ = cast(scene, cam.center, dirs)
    return t, dirs


def sensor_points(scene: SynthScene, cam: Camera, grid: tuple[int, int] = (24, 32)) -> np.ndarray:
    """World points [N, 3] that a sparse grid of rays over the camera's whole photo (:attr:`Camera.sensor`)
    hits: what sparse SfM points of a real photo would sample. Empty without a sensor."""
    if cam.sensor is None:
        return np.zeros((0, 3))
    t, dirs = _sensor_rays(scene, cam, grid)
    hit = np.isfinite(t)
    return cam.center + t[hit, None] * dirs[hit]


def sensor_depth_range(scene: SynthScene, cam: Camera, grid: tuple[int, int] = (24, 32),
                       percentiles: tuple[float, float] = (1.0, 99.0),
                       points: np.ndarray | None = None) -> tuple[float, float] | None:
    """Robust (near, far) z-depth of what the camera's whole photo sees, from a sparse grid of rays: the
    range a cam file or sparse SfM points give for a real photo, of which a training view is only a
    window. With ``points`` (:func:`sensor_points` of the photo), their z-depth in ``cam``, which may be
    turned away from the photo (:func:`centred_window`). None when the camera has no sensor (and no
    points are given) or nothing is hit in front of it."""
    if points is not None:
        z = (points @ cam.R.T + cam.t)[:, 2]
    elif cam.sensor is not None:
        z, _ = _sensor_rays(scene, cam, grid)
    else:
        return None
    z = z[np.isfinite(z) & (z > 0)]
    if len(z) == 0:
        return None
    lo, hi = np.percentile(z, percentiles)
    return float(lo), float(hi)


def centred_window(cam: Camera, width: int, height: int) -> Camera:
    """A window of a photo turned into a photo of its own: the camera rotated about its centre to look
    through the window's middle, the principal point in the middle, the same focal length. It sees
    nearly what the window sees, and its files pass the checks real photos get (a principal point near
    the image centre)."""
    axis = cam.R.T @ (np.linalg.inv(cam.K) @ np.array([width / 2, height / 2, 1.0]))
    z = axis / np.linalg.norm(axis)
    x = cam.R[0] - (cam.R[0] @ z) * z
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    K = cam.K.copy()
    K[0, 1], K[0, 2], K[1, 2] = 0.0, width / 2, height / 2
    return dataclasses.replace(cam, K=K, R=R, t=-R @ cam.center, sensor=None)


def render_view(scene: SynthScene, cam: Camera):
    """(image uint8 [H,W,3], depth float32 [H,W] (0 = nothing hit), world points [H,W,3]).

    Depth and points are exact at pixel centres; with ``scene.supersample`` = s the colour averages
    s x s rays per pixel. The camera's exposure, blur and noise are applied last.
    """
    H, W = scene.height, scene.width
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    dirs = _pixel_rays(cam, xs.ravel() + 0.5, ys.ravel() + 0.5)
    origins = np.broadcast_to(cam.center, dirs.shape)
    t, surf, normals = cast(scene, origins, dirs)
    hit = np.isfinite(t)
    pts = origins + np.where(hit, t, 0)[:, None] * dirs
    ss = max(1, int(scene.supersample))
    if ss == 1:
        rgb = _colour(scene, cam, dirs, t, surf, normals)
    else:
        rgb = np.zeros_like(pts)
        for oy in (np.arange(ss) + 0.5) / ss:
            for ox in (np.arange(ss) + 0.5) / ss:
                d = _pixel_rays(cam, xs.ravel() + ox, ys.ravel() + oy)
                rgb += _colour(scene, cam, d, *cast(scene, origins, d))
        rgb /= ss * ss
    rgb = _camera_effects(rgb.reshape(H, W, 3), cam)
    image = np.round(rgb * 255).astype(np.uint8)
    depth = np.where(hit, t, 0).astype(np.float32).reshape(H, W)
    return image, depth, pts.reshape(H, W, 3)
