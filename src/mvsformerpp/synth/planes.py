"""One textured plane seen by a row of cameras, rendered by exact plane homographies (no ray tracer).

The reference camera sits at the origin looking along +z; the plane passes through (0, 0, ``depth``)
and is tilted by ``tilt_deg`` about the camera's x axis (its far side at the top of the image, as a
floor or a table seen from above) or, with ``tilt_axis="y"``, about its y axis (far side on the right).
The source cameras stand at ``k * baseline`` along x for the offsets ``k``; with ``verge`` they turn to
look at the plane's centre point, else they keep the reference's orientation (a sideways slide: pure
horizontal parallax). The baseline is set from ``disparity``: the
image shift, in pixels, of the plane's centre between neighbouring cameras.

Pixel (x, y) covers [x, x+1) x [y, y+1) and its ray is K^-1 [x + 0.5, y + 0.5, 1], as in
:mod:`mvsformerpp.synth.render`; each photo is the mean of ``supersample``^2 rays per pixel. The
reference's depth is the exact z-depth of the plane on each pixel's centre ray. A plane has no
occlusion and, for a rich texture, a unique match everywhere, so what a depth network gets wrong on
it is geometry alone: a bias in the matching, or slanted surfaces flattened towards fronto-parallel.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.io.mvsnet import MVSNetCam, write_cam
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.synth.photos import procedural_images
from mvsformerpp.synth.writer import save_png
from mvsformerpp.utils.atomic import atomic_write_text

OFFSETS = (0, 1, -1, 2, -2)
"""Camera positions along x in units of the baseline; the first is the reference."""


@dataclass(frozen=True)
class PlaneScene:
    """Photos, cameras and the reference view's exact depth."""

    images: list[np.ndarray]
    """uint8 [H, W, 3] per camera, the reference first."""
    K: np.ndarray
    """[3, 3] shared intrinsics (principal point at the image centre)."""
    extrinsics: list[np.ndarray]
    """[4, 4] world-to-camera per camera (the world frame is the reference camera's)."""
    depth: np.ndarray
    """[H, W] float32 z-depth of the reference view."""
    depth_range: tuple[float, float]
    """A range holding every depth of every view, for the cam files."""


def plane_texture(size: int = 1024) -> np.ndarray:
    """The default texture: coloured 1/f noise from a seed no training run uses."""

    return procedural_images(count=1, size=size, seed=7_000_001)[0]


def _look_at(center: np.ndarray, target: np.ndarray) -> np.ndarray:
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x = x / np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def plane_scene(height: int, width: int, tilt_deg: float = 0.0, verge: bool = False, disparity: float | None = None,
                depth: float = 2.0, focal: float | None = None, texture: np.ndarray | None = None,
                texel_px: float = 0.67, supersample: int = 4, offsets: tuple[int, ...] = OFFSETS,
                tilt_axis: str = "x") -> PlaneScene:
    """Render the scene of the module docstring.

    ``disparity`` defaults to width / 32 pixels (20 at 640 px: the same angles at every size),
    ``focal`` to 1.2 x width; ``texel_px``: one texel's size in reference pixels at the plane's centre
    (below 1: finer than the pixels, so each photo pixel averages a few texels, as a real sensor does).
    ``tilt_axis``: ``x`` tilts the plane about the camera's x axis (depth changes down the image), ``y``
    about its y axis (depth changes across it, the far side on the right).
    """
    if tilt_axis not in ("x", "y"):
        raise ValueError(f"tilt_axis must be 'x' or 'y', got {tilt_axis!r}")
    if not 0.0 <= tilt_deg < 75.0:
        raise ValueError(f"tilt_deg must be in [0, 75) degrees, got {tilt_deg}")
    if height < 8 or width < 8 or supersample < 1:
        raise ValueError(f"need at least 8x8 pixels and supersample >= 1, got {width}x{height}, {supersample}")
    f = 1.2 * width if focal is None else float(focal)
    disparity = width / 32 if disparity is None else float(disparity)
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    K_inv = np.linalg.inv(K)
    tilt = np.deg2rad(tilt_deg)
    normal = (np.array([0.0, -np.sin(tilt), -np.cos(tilt)]) if tilt_axis == "x" else
              np.array([np.sin(tilt), 0.0, -np.cos(tilt)]))
    centre = np.array([0.0, 0.0, depth])
    axis_u = np.cross(normal, [0.0, 1.0, 0.0])  # the plane's own 2-D frame (x-tilt: the camera's x axis)
    axis_u /= np.linalg.norm(axis_u)
    plane = _TexturedPlane(normal, normal @ centre, centre, axis_u, np.cross(normal, axis_u), depth / f * texel_px,
                           tilt_deg)
    tex = torch.from_numpy(plane_texture() if texture is None else texture).permute(2, 0, 1).float()[None] / 255
    baseline = disparity * depth / f
    ys, xs = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    pixels = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])  # [3, HW]
    images, extrinsics, depths = [], [], []
    for k in offsets:
        C = np.array([k * baseline, 0.0, 0.0])
        R = _look_at(C, centre) if verge and k != 0 else np.eye(3)
        images.append(plane.render(tex, K_inv, R, C, pixels, height, width, supersample))
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = R, -R @ C
        extrinsics.append(E)
        depths.append(plane.hits(K_inv, R, C, pixels)[1])
    all_depths = np.concatenate(depths)
    rng = (0.8 * float(all_depths.min()), 1.25 * float(all_depths.max()))
    return PlaneScene(images, K, extrinsics, depths[0].reshape(height, width).astype(np.float32), rng)


@dataclass(frozen=True)
class _TexturedPlane:
    """The plane normal . X = offset, textured in its own 2-D frame (``axis_u``, ``axis_v`` through ``centre``,
    one texel ``texel`` scene units wide)."""

    normal: np.ndarray
    offset: float
    centre: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    texel: float
    tilt_deg: float

    def hits(self, K_inv: np.ndarray, R: np.ndarray, C: np.ndarray, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Plane points [HW, 3] on the rays of ``pix`` ([3, HW]) and their z-depths in the camera (R, centre C)."""
        rays = R.T @ K_inv @ pix  # world directions, z-component 1 in the camera's frame
        s = (self.offset - self.normal @ C) / (self.normal @ rays)
        if np.any(s <= 0):
            raise ValueError(f"a camera sees past the horizon of a plane tilted {self.tilt_deg} degrees; "
                             "lower the tilt or the field of view")
        return (C[:, None] + rays * s).T, s

    def render(self, tex: torch.Tensor, K_inv: np.ndarray, R: np.ndarray, C: np.ndarray, pixels: np.ndarray,
               height: int, width: int, supersample: int) -> np.ndarray:
        """The camera's photo [H, W, 3] uint8: the texture ([1, 3, th, tw] in [0, 1]) averaged over
        ``supersample`` x ``supersample`` rays per pixel."""
        th, tw = tex.shape[-2:]
        acc = torch.zeros(1, 3, height, width)
        for sy in range(supersample):
            for sx in range(supersample):
                jitter = np.array([(sx + 0.5) / supersample - 0.5, (sy + 0.5) / supersample - 0.5, 0.0])
                points, _ = self.hits(K_inv, R, C, pixels + jitter[:, None])
                rel = points - self.centre
                grid = np.stack([rel @ self.axis_u / self.texel / (tw / 2), rel @ self.axis_v / self.texel / (th / 2)],
                                -1)
                grid = torch.from_numpy(grid.reshape(1, height, width, 2)).float()
                acc += F.grid_sample(tex, grid, mode="bilinear", padding_mode="reflection", align_corners=False)
        image = (acc / supersample**2)[0].permute(1, 2, 0).clamp(0, 1).numpy()
        return np.round(image * 255).astype(np.uint8)


def write_plane_scene(out_dir: str | Path, scene: PlaneScene) -> Path:
    """The scene in the MVSNet layout (images, cams, pair.txt by camera distance) with the reference's
    truth as ``depth_gt/00000000.pfm``; returns ``out_dir``."""

    out = Path(out_dir)
    for sub in ("images", "cams", "depth_gt"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    centers = np.stack([-E[:3, :3].T @ E[:3, 3] for E in scene.extrinsics])
    lines = [str(len(scene.images))]
    for i, (image, E) in enumerate(zip(scene.images, scene.extrinsics)):
        save_png(out / "images" / f"{i:08d}.png", image)
        write_cam(out / "cams" / f"{i:08d}_cam.txt", MVSNetCam(extrinsic=E, K=scene.K, depth_min=scene.depth_range[0],
                                                               depth_max=scene.depth_range[1]))
        dist = np.linalg.norm(centers - centers[i], axis=1)
        others = [int(j) for j in np.argsort(dist, kind="stable") if j != i]
        lines += [str(i), f"{len(others)} " + " ".join(f"{j} {1.0 / (1.0 + dist[j]):.4f}" for j in others)]
    atomic_write_text(out / "pair.txt", "\n".join(lines) + "\n")
    write_pfm(out / "depth_gt" / "00000000.pfm", scene.depth)
    return out
