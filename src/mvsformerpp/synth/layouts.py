"""Varied synthetic scenes for training and a held-out style for evaluation.

``training_scene`` draws one of four layouts, each with the camera motion real captures of that kind
have:

- ``table``: objects (some stacked) on a table before walls, cameras on an arc around them with
  5-15 degrees between neighbours (DTU-like);
- ``ring``: one compound object (a small monument: pedestal, columns, dome) seen from a ring with
  10-25 degrees between views, half of the time before an empty black background (Middlebury-like);
- ``room``: inside a furnished room, a handheld camera walking forward or sideways (video-like);
- ``facade``: a building front with balconies, windows, columns and trees before it, most of the time
  under a sky at infinity (:class:`~mvsformerpp.synth.render.Sky`), cameras moving along the street.

Tables, rooms and streets also hold a few thin upright structures (rods, stands, poles: a few pixels
wide, an occlusion boundary on each side).

Surfaces get natural-image textures (:mod:`mvsformerpp.synth.photos`), procedural ones, or nearly
none (``plain_walls``: the share of the walls and ceilings of rooms and tables that are painted one
light colour, as most real rooms' are); some are glossy (a view-dependent highlight). Every view has
its own exposure and white balance, a lens blur (sometimes defocus) and sensor noise; fields of view of
45-75 degrees, slightly off-centre principal points and small camera roll.

``heldout_scene`` is a style the training scenes never contain: tilted ellipsoids, boxes and panels
floating inside a textured dome, textured with procedural images from other seeds, seen from a
spiral path closing in on them. All geometry is analytic, so depth is exact.
"""

from __future__ import annotations

import numpy as np

from mvsformerpp.synth.photos import heldout_texture_set, texture_set
from mvsformerpp.synth.render import Camera, Sky, Surface, SynthScene, cast, look_at
from mvsformerpp.synth.shapes import Box, Cylinder, Ellipsoid, Plane, Rect, Sphere

LAYOUTS = ("table", "ring", "room", "facade")
LAYOUT_WEIGHTS = (0.3, 0.2, 0.25, 0.25)
SOLID = ("noise", "checker", "stripes", "marble")


WALLS = {"room": slice(1, 6), "table": slice(2, 4)}
"""Where the walls (and a room's ceiling) sit in the surface lists of the layouts that have them."""


# ----------------------------------------------------------------------------------------- materials
def _material(rng: np.random.Generator, shape, extent: float, frame: np.ndarray | None = None,
              flat_p: float = 0.15, photo_p: float = 0.55) -> Surface:
    """A surface of ``shape`` (typical size ``extent``) with a random texture and finish."""
    seed = int(rng.integers(1 << 30))
    r = rng.random()
    if r < photo_p:
        colors = np.stack([rng.uniform(0, 1, 3), rng.uniform(0.6, 1.0, 3)])  # tint: base, photo weight
        texels = 384.0 / (extent * rng.uniform(0.4, 2.0))
        surf = Surface(shape, "photo", colors, seed, photo=int(rng.integers(1 << 16)), texels_per_unit=texels,
                       frame=frame)
    elif r < 1 - flat_p:
        surf = Surface(shape, str(rng.choice(SOLID)), rng.uniform(0.05, 0.95, (2, 3)), seed,
                       scale=rng.uniform(0.6, 2.0) / extent)
    else:  # low texture: one colour, only shading varies
        c = rng.uniform(0.2, 0.95, 3)
        surf = Surface(shape, "flat", np.stack([c, c * rng.uniform(0.9, 1.0)]), seed, scale=1.0 / extent)
    if rng.random() < 0.3:
        surf.specular, surf.shininess = rng.uniform(0.15, 0.7), rng.uniform(8, 80)
    return surf


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _box(rng, center, half, yaw, **kw) -> Surface:
    return _material(rng, Box(np.asarray(center, float), np.asarray(half, float), yaw), 2 * float(np.max(half)),
                     frame=_yaw(yaw), **kw)


def _thin_structures(extra: np.random.Generator, count: int, xy_low, xy_high, radius, height,
                     base: float = 0.0) -> list[Surface]:
    """``count`` upright thin cylinders (rods, stands, poles) at random (x, y) in the box [xy_low, xy_high]:
    the structures a few pixels wide whose both sides are occlusion boundaries in real photos."""
    out = []
    for _ in range(count):
        xy = extra.uniform(xy_low, xy_high)
        r, h = extra.uniform(*radius), extra.uniform(*height)
        out.append(_material(extra, Cylinder(np.asarray(xy, float), r, base, h), max(4 * r, h / 4)))
    return out


# ------------------------------------------------------------------------------------------- cameras
def _intrinsics(rng: np.random.Generator, width: int, height: int, fov_deg=(22, 75)) -> np.ndarray:
    """Horizontal field of view from telephoto-like (DTU, Middlebury: 25-35 degrees) to phone-wide."""
    fov = np.deg2rad(rng.uniform(*fov_deg))
    f = width / 2 / np.tan(fov / 2)
    cx = width / 2 + rng.uniform(-0.03, 0.03) * width
    cy = height / 2 + rng.uniform(-0.03, 0.03) * height
    return np.array([[f, 0, cx], [0, f * rng.uniform(0.995, 1.005), cy], [0, 0, 1.0]])


def _sensor_size(rng: np.random.Generator, width: int, height: int, sensor_width) -> tuple[int, int]:
    """Size of the photo a ``width`` x ``height`` view is a window of: its width log-uniform in
    ``sensor_width`` = (low, high) pixels (never below the view), the view's aspect ratio."""
    if sensor_width is None:
        return width, height
    lo, hi = (float(v) for v in sensor_width)
    if not 0 < lo <= hi:
        raise ValueError(f"sensor_width {sensor_width} must be two widths 0 < low <= high (pixels)")
    w = max(width, int(round(np.exp(rng.uniform(np.log(lo), np.log(hi))))))
    return w, max(height, int(round(w * height / width)))


WINDOW_JITTER = 0.1
"""Largest offset of a window's centre from the anchor's projection, as a fraction of the window's size."""


def _cut_windows(rng: np.random.Generator, scene: SynthScene, sensor: tuple[int, int]) -> None:
    """Make every camera of ``scene`` (intrinsics of a ``sensor``-sized photo) a window of the scene's size.

    A real training crop is a window of a high-resolution photo: a long focal length in pixels, and so
    the image shift per depth hypothesis that real photos have. All windows look at one anchor, a surface
    point seen near a random spot of one photo (the next photo where all 32 candidate rays miss) and, of
    those candidates, the first that every photo sees unoccluded (else the one most photos see). Each
    window is placed around the anchor's projection with a random offset of at most :data:`WINDOW_JITTER`
    of its size and kept inside its photo, so the views overlap as crops around one place of a scene do:
    where the windows were placed with a quarter of their size of offset around an anchor that some photos
    did not see, a reference pixel was inside a source window for half of the pixels only (0.50 against
    0.79 for whole small photos).
    """
    wf, hf = sensor
    w, h = scene.width, scene.height
    if (wf, hf) == (w, h):
        return
    K = scene.cameras[0].K.copy()
    n = len(scene.cameras)
    start = int(rng.integers(n))
    anchor = None
    for k in range(n):  # a photo whose rays all miss (sky only) hands over to the next photo
        first = scene.cameras[(start + k) % n]
        px = np.clip(rng.normal(0.5, 0.22, (32, 2)), 0.05, 0.95) * (wf, hf)
        dirs = np.concatenate([px, np.ones((32, 1))], 1) @ np.linalg.inv(K).T @ first.R
        t, _, _ = cast(scene, first.center, dirs)
        hit = np.flatnonzero(np.isfinite(t))
        if len(hit):
            points = first.center + t[hit, None] * dirs[hit]
            anchor = points[int(np.argmax(_photos_seeing(scene, K, points, wf, hf)))]  # argmax: the first best
            break
    if anchor is None:  # nothing anywhere: the windows stay in the photos' middles
        anchor = scene.cameras[start].center + scene.cameras[start].R[2]
    for cam in scene.cameras:
        p = K @ (cam.R @ anchor + cam.t)
        u, v = (p[:2] / p[2]) if p[2] > 0 else (wf / 2, hf / 2)
        jitter = rng.uniform(-WINDOW_JITTER, WINDOW_JITTER, 2) * (w, h)
        x0 = np.round(np.clip(u - w / 2 + jitter[0], 0, wf - w))  # whole pixels: an exact crop
        y0 = np.round(np.clip(v - h / 2 + jitter[1], 0, hf - h))
        cam.K = K.copy()
        cam.K[0, 2] -= x0
        cam.K[1, 2] -= y0
        cam.sensor = (K.copy(), wf, hf)


def _photos_seeing(scene: SynthScene, K: np.ndarray, points: np.ndarray, width: int, height: int) -> np.ndarray:
    """For each world point [N, 3], the number of the scene's cameras (with photo intrinsics ``K``) that see
    it inside their ``width`` x ``height`` photo, in front of them and not hidden by another surface."""
    seen = np.zeros(len(points), dtype=np.int64)
    for cam in scene.cameras:
        cam_pts = points @ cam.R.T + cam.t
        z = cam_pts[:, 2]
        uv = cam_pts @ K.T
        u, v = uv[:, 0] / np.maximum(z, 1e-9), uv[:, 1] / np.maximum(z, 1e-9)
        inside = (z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        dirs = (points - cam.center) / np.maximum(z, 1e-9)[:, None]  # t along these rays is the z-depth
        t, _, _ = cast(scene, cam.center, dirs)
        seen += inside & (np.abs(t - z) <= 1e-3 * np.maximum(z, 1e-9))
    return seen


def _framing_distance(rng: np.random.Generator, K: np.ndarray, half_extent: float) -> float:
    """Distance at which an object of ``half_extent`` fills about a third to two thirds of the image width."""
    width = 2 * K[0, 2]
    return half_extent * 2 * K[0, 0] / width * np.exp(rng.uniform(np.log(1.5), np.log(3.0)))


def _pose(center: np.ndarray, target: np.ndarray, roll: float) -> tuple[np.ndarray, np.ndarray]:
    R, _ = look_at(center, target)
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ R
    return R, -R @ center


def _cameras(rng: np.random.Generator, K: np.ndarray, centers: list, targets: list, roll_deg: float) -> list[Camera]:
    """Cameras with per-view exposure, white balance, blur and noise (shared tendencies per scene)."""
    base_gain = np.exp(rng.normal(0, 0.15))
    blur_p, noise = rng.uniform(0, 0.6), rng.uniform(0.0, 0.02)
    cams = []
    for c, tg in zip(centers, targets):
        R, t = _pose(np.asarray(c, float), np.asarray(tg, float), np.deg2rad(rng.normal(0, roll_deg)))
        gain = base_gain * np.exp(rng.normal(0, 0.08)) * rng.uniform(0.93, 1.07, 3)
        blur = rng.uniform(0.6, 1.4) if rng.random() < blur_p else rng.uniform(0.25, 0.5)  # defocus or lens PSF
        cams.append(Camera(K.copy(), R, t, gain=gain, blur=blur, noise=noise * rng.uniform(0.5, 1.5),
                           noise_seed=int(rng.integers(1 << 30))))
    return cams


def _paint(rng: np.random.Generator, surf: Surface) -> None:
    """Paint ``surf`` one light, slightly tinted colour: only the shading varies over it (no texture to
    match), sometimes with a faint sheen, as painted plaster."""
    c = rng.uniform(0.55, 0.95) * (1 + rng.uniform(-0.06, 0.06, 3))
    surf.texture, surf.colors, surf.photo = "flat", np.stack([c, c * rng.uniform(0.97, 1.0)]), 0
    surf.specular = rng.uniform(0.03, 0.12) if rng.random() < 0.3 else 0.0
    surf.shininess = rng.uniform(4, 16)


def _ring(rng, n: int, target: np.ndarray, radius: float, elevation_deg: float, step_deg: float, jitter: float):
    """Centres on an arc about ``target`` with ``step_deg`` between neighbours, and their look-at points."""
    start = rng.uniform(0, 2 * np.pi)
    centers, targets = [], []
    for i in range(n):
        az = start + np.deg2rad(step_deg) * i
        el = np.deg2rad(elevation_deg + rng.normal(0, 2))
        r = radius * np.exp(rng.normal(0, 0.04))
        centers.append(target + r * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]))
        targets.append(target + rng.normal(0, jitter, 3))
    return centers, targets


def _walk(rng, n: int, start: np.ndarray, direction: np.ndarray, step: float, look: np.ndarray, jitter: float):
    """Handheld-like motion: centres along ``direction`` with shake, looking along ``look`` with wobble."""
    direction = direction / np.linalg.norm(direction)
    centers, targets = [], []
    for i in range(n):
        c = start + direction * step * i + rng.normal(0, 0.15 * step, 3)
        centers.append(c)
        targets.append(c + look + rng.normal(0, jitter * np.linalg.norm(look), 3))
    return centers, targets


# ------------------------------------------------------------------------------------------- layouts
def _table(rng, n_views, K, n_objects, extra):
    surfaces = []
    hx, hy = rng.uniform(0.7, 1.4, 2)
    surfaces.append(_box(rng, (0, 0, -0.04), (hx, hy, 0.04), rng.uniform(0, np.pi), flat_p=0.1))
    surfaces.append(_material(rng, Plane(np.array([0, 0, 1.0]), -0.75), 3.0))
    radius = _framing_distance(rng, K, 0.45)
    for axis, sign in ((0, -1), (1, rng.choice([-1, 1]))):  # two walls, beyond the cameras
        normal = np.eye(3)[axis]
        surfaces.append(_material(rng, Plane(normal, sign * (radius + rng.uniform(0.3, 2.5))), 3.0))
    n = n_objects if n_objects is not None else int(rng.integers(2, 7))
    for _ in range(n):
        x, y = rng.uniform(-0.5, 0.5, 2)
        size = rng.uniform(0.06, 0.25)
        base = rng.choice([0.0, 0.0, 0.0, rng.uniform(0.05, 0.2)])  # some objects stand on a block
        if base > 0:
            surfaces.append(_box(rng, (x, y, base / 2), (size * 1.3, size * 1.3, base / 2), rng.uniform(0, np.pi)))
        kind = rng.choice(["sphere", "box", "cylinder"])
        if kind == "sphere":
            surfaces.append(_material(rng, Sphere(np.array([x, y, base + size]), size), 2 * size))
        elif kind == "box":
            half = size * rng.uniform(0.5, 1.5, 3)
            surfaces.append(_box(rng, (x, y, base + half[2]), half, rng.uniform(0, np.pi)))
        else:
            surfaces.append(_material(rng, Cylinder(np.array([x, y]), size * 0.7, base, size * rng.uniform(1, 4)),
                                      2 * size))
    target = np.array([0, 0, 0.1]) + rng.normal(0, 0.05, 3)
    centers, targets = _ring(rng, n_views, target, radius, rng.uniform(15, 50),
                             rng.uniform(5, 15) * rng.choice([-1, 1]), 0.05)
    surfaces += _thin_structures(extra, int(extra.integers(0, 4)), (-0.6, -0.6), (0.6, 0.6), (0.003, 0.012),
                                 (0.08, 0.4))  # pencils, rods, stems
    return surfaces, centers, targets


def _ring_object(rng, n_views, K, n_objects):
    surfaces = []
    plaster = rng.random() < 0.5  # one light colour: the shading is the only texture (like the temple)
    kw = dict(flat_p=1.0, photo_p=0.0) if plaster else {}
    w = rng.uniform(0.15, 0.3)
    surfaces.append(_box(rng, (0, 0, 0.04), (w * 1.3, w * 1.3, 0.04), 0.0, **kw))  # pedestal
    top = 0.08 + rng.uniform(0.25, 0.5)
    ncol = int(rng.integers(2, 7))
    for k in range(ncol):
        a = 2 * np.pi * k / ncol
        r = rng.uniform(0.03, 0.05)
        surfaces.append(_material(rng, Cylinder(np.array([np.cos(a), np.sin(a)]) * w, r, 0.08, top - 0.08),
                                  4 * r, **kw))
    surfaces.append(_box(rng, (0, 0, top + 0.03), (w * 1.2, w * 1.2, 0.03), rng.uniform(0, np.pi / 4), **kw))
    if rng.random() < 0.6:
        surfaces.append(_material(rng, Sphere(np.array([0, 0, top + 0.06]), w * rng.uniform(0.6, 1.0)), w, **kw))
    for _ in range(n_objects if n_objects is not None else int(rng.integers(0, 3))):
        s = rng.uniform(0.03, 0.08)
        surfaces.append(_material(rng, Sphere(np.array([*rng.uniform(-w, w, 2), rng.uniform(0.1, top)]), s),
                                  2 * s, **kw))
    if plaster:
        c = rng.uniform(0.7, 1.0) * np.array([1.0, rng.uniform(0.9, 1.0), rng.uniform(0.8, 1.0)])
        for s in surfaces:
            s.colors = np.stack([c, c])
    void = rng.random() < 0.5
    if not void:
        surfaces.append(_material(rng, Plane(np.array([0, 0, 1.0]), 0.0), 2.0))
    target = np.array([0, 0, top / 2]) + rng.normal(0, 0.02, 3)
    centers, targets = _ring(rng, n_views, target, _framing_distance(rng, K, max(w * 1.3, top / 2)),
                             rng.uniform(10, 45),
                             rng.uniform(10, 25) * rng.choice([-1, 1]), 0.02)
    return surfaces, centers, targets, void, plaster


def _room(rng, n_views, K, n_objects, extra):
    sx, sy, sz = rng.uniform(3, 7), rng.uniform(3, 6), rng.uniform(2.4, 3.2)
    surfaces = [_material(rng, Plane(np.array([0, 0, 1.0]), 0.0), 2.0, flat_p=0.05),
                _material(rng, Plane(np.array([0, 0, 1.0]), sz), 2.0, flat_p=0.3)]
    for axis, half in ((0, sx / 2), (1, sy / 2)):
        for sign in (-1, 1):
            surfaces.append(_material(rng, Plane(np.eye(3)[axis], sign * half), 2.0, flat_p=0.12))
    n = n_objects if n_objects is not None else int(rng.integers(3, 9))
    for _ in range(n):
        kind = rng.choice(["furniture", "furniture", "item", "picture"])
        if kind == "picture":
            axis, sign = int(rng.integers(2)), rng.choice([-1, 1])
            half = (sx / 2, sy / 2)[axis] - 0.01
            u = np.eye(3)[1 - axis]
            center = np.eye(3)[axis] * sign * half + u * rng.uniform(-0.35, 0.35) * (sy, sx)[axis]
            center[2] = rng.uniform(1.0, 2.0)
            surfaces.append(_material(rng, Rect(center, u, np.array([0, 0, 1.0]), rng.uniform(0.2, 0.6),
                                                rng.uniform(0.2, 0.5)), 0.6, flat_p=0.0, photo_p=0.9))
        else:
            fw, fd = rng.uniform(0.3, 1.0, 2)
            fh = rng.uniform(0.3, 1.8) if kind == "furniture" else rng.uniform(0.05, 0.2)
            x, y = rng.uniform(-sx / 2 + fw, sx / 2 - fw), rng.uniform(-sy / 2 + fd, sy / 2 - fd)
            z0 = 0.0 if kind == "furniture" else rng.uniform(0.4, 0.9)
            if kind == "item" and rng.random() < 0.5:
                surfaces.append(_material(rng, Cylinder(np.array([x, y]), fh * 0.6, z0, fh * 2), fh * 2))
            else:
                fw, fd = (fw, fd) if kind == "furniture" else (fh, fh)
                surfaces.append(_box(rng, (x, y, z0 + fh / 2), (fw / 2, fd / 2, fh / 2), rng.uniform(0, np.pi)))
    yaw = rng.uniform(0, 2 * np.pi)
    look = np.array([np.cos(yaw), np.sin(yaw), rng.uniform(-0.3, 0.1)])
    side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    start = np.array([-np.cos(yaw) * sx * 0.3, -np.sin(yaw) * sy * 0.3, rng.uniform(1.1, 1.8)])
    mix = rng.uniform(0, 1)
    direction = mix * look * np.array([1, 1, 0]) + (1 - mix) * side * rng.choice([-1, 1])
    centers, targets = _walk(rng, n_views, start, direction, rng.uniform(0.05, 0.25), look, 0.05)
    margin = np.array([sx / 2 - 0.3, sy / 2 - 0.3, sz - 0.3])
    centers = [np.clip(c, -margin, margin) for c in centers]  # stay inside the room
    surfaces += _thin_structures(extra, int(extra.integers(0, 4)), (-sx / 2 + 0.2, -sy / 2 + 0.2),
                                 (sx / 2 - 0.2, sy / 2 - 0.2), (0.008, 0.025), (0.4, 1.8))  # stands, legs, stems
    return surfaces, centers, targets


def _facade(rng, n_views, K, n_objects, extra):
    width, height = rng.uniform(8, 20), rng.uniform(6, 15)
    # the front ends at the roof line and a few metres beyond the bays: the sky shows above and beside it
    front = Rect(np.array([0.0, 0.0, height / 2]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), width / 2 + 4.0,
                 height / 2)
    surfaces = [_material(rng, front, 6.0, flat_p=0.1),
                _material(rng, Plane(np.array([0, 0, 1.0]), 0.0), 6.0, flat_p=0.05)]
    floors, bays = int(height // 3), int(width // 3)
    for f in range(max(floors, 1)):
        for b in range(max(bays, 1)):
            if rng.random() < 0.6:
                y, z = -width / 2 + (b + 0.5) * 3, 1.5 + 3 * f
                glass = _material(rng, Rect(np.array([0.02, y, z]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]),
                                            0.6, 0.8), 1.5, flat_p=0.5)
                glass.specular, glass.shininess = rng.uniform(0.3, 0.8), rng.uniform(20, 100)
                surfaces.append(glass)
            if f > 0 and rng.random() < 0.25:
                surfaces.append(_box(rng, (0.4, -width / 2 + (b + 0.5) * 3, 3 * f + 0.1), (0.4, 1.0, 0.1), 0.0))
    n = n_objects if n_objects is not None else int(rng.integers(1, 5))
    for _ in range(n):  # columns, trees and cars between the street and the wall
        x, y = rng.uniform(1, 4), rng.uniform(-width / 2, width / 2)
        kind = rng.choice(["column", "tree", "car"])
        if kind == "column":
            surfaces.append(_material(rng, Cylinder(np.array([x, y]), rng.uniform(0.15, 0.4), 0.0, height * 0.7), 1))
        elif kind == "tree":
            surfaces.append(_material(rng, Cylinder(np.array([x, y]), 0.15, 0.0, 2.5), 0.5))
            surfaces.append(_material(rng, Sphere(np.array([x, y, 3.2]), rng.uniform(0.8, 1.5)), 2.0))
        else:
            surfaces.append(_box(rng, (x, y, 0.75), (0.9, 2.1, 0.75), rng.uniform(-0.2, 0.2)))
    dist = rng.uniform(5, 14)
    yaw = np.deg2rad(rng.uniform(-25, 25))
    look = np.array([-np.cos(yaw), np.sin(yaw), rng.uniform(0.0, 0.25)]) * dist
    start = np.array([dist, rng.uniform(-width / 4, width / 4), rng.uniform(1.5, 3.0)])
    if extra.random() < 0.4:  # looking up at the upper floors and the sky, the roof line still in view
        look[2] = max(look[2], min(look[2] + extra.uniform(0.2, 0.6) * dist, 0.85 * height - 3.0))
    mix = rng.uniform(0, 0.5)
    direction = np.array([-mix, (1 - mix) * rng.choice([-1, 1]), 0.0])
    centers, targets = _walk(rng, n_views, start, direction, rng.uniform(0.2, 0.9), look, 0.03)
    surfaces += _thin_structures(extra, int(extra.integers(0, 4)), (1.5, -width / 2), (min(4.5, dist - 1), width / 2),
                                 (0.03, 0.08), (3.0, 7.0))  # lamp posts, sign poles
    return surfaces, centers, targets


def _sky(extra: np.random.Generator) -> Sky:
    """A daylight sky: pale at the horizon, deeper towards the zenith, clear to overcast."""
    zenith = np.array([0.25, 0.45, 0.85]) * extra.uniform(0.6, 1.1) + extra.uniform(-0.08, 0.08, 3)
    horizon = np.array([0.75, 0.82, 0.9]) * extra.uniform(0.8, 1.1) + extra.uniform(-0.05, 0.05, 3)
    return Sky(np.clip(horizon, 0, 1), np.clip(zenith, 0, 1), float(extra.uniform(0, 1)),
               int(extra.integers(1 << 30)))


def training_scene(seed: int, num_views: int = 7, height: int = 256, width: int = 320,
                   num_objects: int | None = None, layout: str | None = None,
                   sensor_width: tuple[float, float] | None = None, plain_walls: float = 0.0,
                   textures: str | None = None) -> SynthScene:
    """A random scene of one of :data:`LAYOUTS` (``layout`` None = drawn from the seed).

    ``sensor_width`` (low, high): the views are ``width`` x ``height`` windows of photos whose width is
    drawn from this range (see :func:`_cut_windows`); None: each view is a whole photo of that size.
    ``plain_walls``: probability that each wall and ceiling of a ``room`` or ``table`` layout is painted
    one light colour (:func:`_paint`); 0 leaves every scene as it was.
    ``textures``: a texture library folder for the photo surfaces (None: :func:`texture_set`'s default).
    """
    if not 0.0 <= plain_walls <= 1.0:
        raise ValueError(f"plain_walls is a probability in [0, 1], got {plain_walls}")
    rng = np.random.default_rng([seed, 11])
    extra = np.random.default_rng([seed, 31])  # the later additions draw apart: the scenes before them stay
    kind = layout if layout is not None else str(rng.choice(LAYOUTS, p=LAYOUT_WEIGHTS))
    if kind not in LAYOUTS:
        raise ValueError(f"unknown layout {kind!r}; choose one of {LAYOUTS}")
    sensor = _sensor_size(rng, width, height, sensor_width)
    K = _intrinsics(rng, *sensor)
    void, plaster = False, False
    if kind == "table":
        surfaces, centers, targets = _table(rng, num_views, K, num_objects, extra)
    elif kind == "ring":
        surfaces, centers, targets, void, plaster = _ring_object(rng, num_views, K, num_objects)
    elif kind == "room":
        surfaces, centers, targets = _room(rng, num_views, K, num_objects, extra)
    else:
        surfaces, centers, targets = _facade(rng, num_views, K, num_objects, extra)
    if plain_walls > 0 and kind in WALLS:
        paint = np.random.default_rng([seed, 47])  # its own stream: the rest of the scene stays as it was
        for surf in surfaces[WALLS[kind]]:
            if paint.random() < plain_walls:
                _paint(paint, surf)
    cams = _cameras(rng, K, centers, targets, roll_deg=2.0 if kind in ("room", "facade") else 1.0)
    light = rng.normal(0, 1, 3) + np.array([0, 0, 1.5])
    scene = SynthScene(surfaces, cams, width, height, {"seed": seed, "style": "train", "layout": kind},
                       light=light / np.linalg.norm(light),
                       ambient=rng.uniform(0.1, 0.3) if plaster else rng.uniform(0.25, 0.6),
                       background=rng.uniform(0, 0.06, 3) if void else rng.uniform(0, 1, 3),
                       supersample=1, textures=texture_set(textures)[1],  # the lens blur smooths edges: 4x faster
                       sky=_sky(extra) if kind == "facade" and extra.random() < 0.8 else None)
    _cut_windows(rng, scene, sensor)
    return scene


def heldout_scene(seed: int, num_views: int = 7, height: int = 256, width: int = 320,
                  num_objects: int | None = None, sensor_width: tuple[float, float] | None = None) -> SynthScene:
    """The evaluation style: tilted shapes floating in a textured dome, a spiral camera path
    (``sensor_width`` as in :func:`training_scene`)."""
    rng = np.random.default_rng([seed, 23])
    sensor = _sensor_size(rng, width, height, sensor_width)
    K = _intrinsics(rng, *sensor)
    kw = dict(photo_p=0.6, flat_p=0.1)
    surfaces = [_material(rng, Sphere(np.zeros(3), rng.uniform(5, 9)), 8.0, **kw)]  # seen from inside
    n = num_objects if num_objects is not None else int(rng.integers(4, 10))
    for _ in range(n):
        c = rng.uniform(-1.2, 1.2, 3)
        kind = rng.choice(["ellipsoid", "panel", "box"])
        size = rng.uniform(0.2, 0.6)
        if kind == "ellipsoid":
            rot = _random_rotation(rng)
            surfaces.append(_material(rng, Ellipsoid(c, size * rng.uniform(0.4, 1.2, 3), rot), 2 * size, rot, **kw))
        elif kind == "panel":
            rot = _random_rotation(rng)
            surfaces.append(_material(rng, Rect(c, rot[:, 0], rot[:, 1], size, size * rng.uniform(0.4, 1.0)),
                                      2 * size, rot, **kw))
        else:
            surfaces.append(_box(rng, c, size * rng.uniform(0.4, 1.0, 3), rng.uniform(0, np.pi), **kw))
    radius0, turn = rng.uniform(2.8, 4.0), rng.uniform(4, 12) * rng.choice([-1, 1])
    start, rise = rng.uniform(0, 2 * np.pi), rng.uniform(-0.15, 0.15)
    centers, targets = [], []
    for i in range(num_views):
        a = start + np.deg2rad(turn) * i
        r = radius0 * (1 - 0.04 * i)
        centers.append(np.array([r * np.cos(a), r * np.sin(a), 0.3 + rise * i]))
        targets.append(rng.normal(0, 0.15, 3))
    cams = _cameras(rng, K, centers, targets, roll_deg=4.0)
    light = rng.normal(0, 1, 3)
    scene = SynthScene(surfaces, cams, width, height, {"seed": seed, "style": "heldout", "layout": "dome"},
                       light=light / np.linalg.norm(light), ambient=rng.uniform(0.3, 0.5),
                       background=np.zeros(3), supersample=2, textures=heldout_texture_set())
    _cut_windows(rng, scene, sensor)
    return scene
