"""Confidence-weighted TSDF integration of depth maps (PyTorch, on the caller's device).

Curless and Levoy (SIGGRAPH 1996), as KinectFusion and Open3D's ScalableTSDFVolume run it: every
voxel centre is projected into each view; where the view has a depth ``d`` at that pixel and the
voxel's z-depth ``z`` satisfies ``d - z > -truncation``, the truncated signed distance
``clamp((d - z) / truncation, -1, 1)`` joins the voxel's running mean with the pixel's confidence as
weight (positive = in front of the surface). Colours are averaged the same way near the surface
(``|d - z| < truncation``). The zero level set, extracted with marching cubes
(:mod:`mvsformerpp.meshing.extract`), is the surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from mvsformerpp.errors import InputError
from mvsformerpp.fusion.core import FusionView
from mvsformerpp.geometry.camera import depth_to_points, project

MAX_TRUNCATION = 100.0
"""Largest truncation in voxels: the grid is padded by the band on every side, and a wider band smears every
surface over more voxels than a scene box holds along its side."""
MIN_VOXELS_PER_SIDE = 8
"""Fewest voxels along the scene box's longest side (what ``--resolution`` allows): coarser grids hold no
surface for marching cubes to find."""


@dataclass(frozen=True)
class TSDFConfig:
    """Settings of :func:`integrate`."""

    voxel: float | None = None
    """Voxel edge in scene units; None: from ``resolution``, or else from the depth maps' own sampling (the
    median size of a pixel on the surface, times :data:`PIXELS_PER_VOXEL`), coarser only where the grid
    would not fit ``max_voxels``."""
    resolution: int | None = None
    """Voxels along the longest side of the scene box when ``voxel`` is None (None: from the sampling)."""
    truncation: float = 4.0
    """Truncation distance in voxels (the band around the surface that a depth sample updates), at most
    :data:`MAX_TRUNCATION`."""
    min_confidence: float = 0.0
    """Depth pixels at or below this confidence are ignored (others weigh by their confidence)."""
    max_voxels: int = 400_000_000
    """Refuse grids larger than this (memory: about 20 bytes per voxel)."""
    chunk: int = 1 << 21
    """Voxels projected at once."""


@dataclass
class TSDFVolume:
    """The integrated grid: voxel (i, j, k) has its centre at ``origin + (i + 0.5, j + 0.5, k + 0.5) * voxel``."""

    tsdf: torch.Tensor  # [X, Y, Z] in [-1, 1] (truncation units), 1 where never updated
    weight: torch.Tensor  # [X, Y, Z] summed confidences
    color: torch.Tensor  # [X, Y, Z, 3] mean colour in [0, 255]
    origin: np.ndarray  # [3]
    voxel: float


def scene_box(views: list[FusionView], percentile: float = 0.5, stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of the depth maps' points (every ``stride``-th pixel, robust ``percentile`` ends)."""
    pts = []
    for v in views:
        P = depth_to_points(v.depth, v.K, v.E)[::stride, ::stride]
        ok = v.depth[::stride, ::stride] > 0
        pts.append(P[ok].cpu())
    if not pts or sum(len(p) for p in pts) == 0:
        raise InputError("the depth maps hold no depth at all: nothing to mesh")
    allp = torch.cat(pts).double().numpy()
    return np.percentile(allp, percentile, axis=0), np.percentile(allp, 100 - percentile, axis=0)


BYTES_PER_VOXEL = 16
"""TSDF value, weight and colour of a voxel, with the working copies (measured: about 15)."""
PIXELS_PER_VOXEL = 1.5
"""Default voxel edge in pixel footprints: about the detail the depth maps resolve, no finer."""


def surface_box(points: np.ndarray, percentile: float = 0.5, margin: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Box of the confident surface: the ``percentile`` / ``100 - percentile`` ends of ``points`` [N, 3] per
    axis (a few stray points do not stretch it), widened by ``margin`` of its extent on every side."""
    if len(points) == 0:
        raise InputError("the reconstruction holds no confident point: nothing to mesh")
    lo, hi = np.percentile(points, percentile, axis=0), np.percentile(points, 100 - percentile, axis=0)
    pad = margin * (hi - lo).max()
    return lo - pad, hi + pad


def pixel_footprint(views: list[FusionView], stride: int = 8) -> float:
    """Median size in scene units of one depth-map pixel on the surface it sees (z-depth / focal length)."""
    sizes = []
    for v in views:
        d = v.depth[::stride, ::stride]
        ok = d > 0
        if ok.any():
            sizes.append(d[ok].double().cpu().numpy() / float(v.K[0, 0]))
    if not sizes:
        raise InputError("the depth maps hold no depth at all: nothing to mesh")
    return float(np.median(np.concatenate(sizes)))


@dataclass(frozen=True)
class GridPlan:
    """Where the TSDF grid lies and how fine it is."""

    lo: np.ndarray
    voxel: float
    dims: np.ndarray
    note: str
    """How the voxel size was chosen (for the console)."""

    @property
    def voxels(self) -> int:
        return int(np.prod(self.dims))


def plan_grid(views: list[FusionView], config: TSDFConfig = TSDFConfig(),
              box: tuple[np.ndarray, np.ndarray] | None = None) -> GridPlan:
    """The grid over ``box`` (default: the depth maps' robust box, :func:`scene_box`): the voxel of ``config``
    or from the sampling, padded by the truncation band; refused (explicit voxel) or coarsened (chosen
    voxel) where it exceeds ``config.max_voxels``."""
    lo, hi = box if box is not None else scene_box(views)
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    extent = float((hi - lo).max())
    if config.voxel:
        voxel, note = float(config.voxel), "given"
    elif config.resolution:
        voxel, note = extent / config.resolution, f"box / {config.resolution}"
    else:
        voxel, note = PIXELS_PER_VOXEL * pixel_footprint(views), f"{PIXELS_PER_VOXEL:g} pixel footprints"
    if not voxel > 0:
        raise InputError(f"--voxel must be positive, got {voxel}")
    if not 0 < config.truncation <= MAX_TRUNCATION:
        raise InputError(f"--truncation must be a number of voxels in (0, {MAX_TRUNCATION:g}], got "
                         f"{config.truncation:g} (the grid is padded by it on every side)")
    if config.voxel and extent / voxel < MIN_VOXELS_PER_SIDE:
        raise InputError(f"--voxel {voxel:g} is larger than an eighth of the scene box's longest side "
                         f"({extent:.4g}): the grid would have fewer than {MIN_VOXELS_PER_SIDE} voxels across the "
                         f"scene and no surface to extract; choose at most --voxel {extent / MIN_VOXELS_PER_SIDE:.4g}")

    def dims_for(v: float) -> np.ndarray:
        t = config.truncation * v
        return np.maximum(np.ceil((hi - lo + 2 * t) / v), 2)  # (floats: no overflow before the check below)

    dims = dims_for(voxel)
    if float(np.prod(dims)) > config.max_voxels:
        needed = voxel * (np.prod(dims) / config.max_voxels) ** (1 / 3)
        if config.voxel or config.resolution:
            raise InputError(f"a {dims[0]:.0f}x{dims[1]:.0f}x{dims[2]:.0f} voxel grid is too large at --voxel "
                             f"{voxel:.4g}; use a larger voxel (at least {needed:.4g})")
        while float(np.prod(dims)) > config.max_voxels:
            voxel, needed = needed, needed * 1.01
            dims = dims_for(voxel)
        note += f", coarsened to fit {config.max_voxels:,} voxels"
    return GridPlan(lo - config.truncation * voxel, voxel, dims.astype(np.int64), note)


def integrate(views: list[FusionView], config: TSDFConfig = TSDFConfig(), progress=None,
              plan: GridPlan | None = None) -> TSDFVolume:
    """Integrate the views' depth maps (confidence as weight) into a TSDF grid (``plan``, default
    :func:`plan_grid` over the depth maps' box)."""
    plan = plan or plan_grid(views, config)
    lo, voxel, dims = plan.lo, plan.voxel, plan.dims
    trunc = config.truncation * voxel
    device = views[0].depth.device
    n = int(np.prod(dims))
    tsdf = torch.ones(n, device=device)
    weight = torch.zeros(n, device=device)
    color = torch.zeros((n, 3), device=device)  # confidence-weighted sums, divided at the end
    color_weight = torch.zeros(n, device=device)
    origin = torch.as_tensor(lo, dtype=torch.float32, device=device)
    for view in views:
        H, W = view.depth.shape
        K, E = view.K.float(), view.E.float()
        depth = torch.where(view.confidence > config.min_confidence, view.depth, torch.zeros_like(view.depth))
        for s in range(0, n, config.chunk):
            idx = torch.arange(s, min(s + config.chunk, n), device=device)
            ijk = torch.stack((idx // (dims[1] * dims[2]), (idx // dims[2]) % dims[1], idx % dims[2]), 1)
            X = origin + (ijk.float() + 0.5) * voxel
            u, v, z = project(K, E, X)
            inside = (u >= 0) & (u < W) & (v >= 0) & (v < H) & (z > 0)
            ui, vi = u.clamp(0, W - 1).long(), v.clamp(0, H - 1).long()
            d = depth[vi, ui]
            sdf = d - z
            upd = inside & (d > 0) & (sdf > -trunc)
            if not upd.any():
                continue
            i, sdf, pix = idx[upd], sdf[upd], (vi * W + ui)[upd]
            w = view.confidence.reshape(-1)[pix].clamp(min=1e-3)
            t = (sdf / trunc).clamp(-1.0, 1.0)
            w0 = weight[i]
            tsdf[i] = (tsdf[i] * w0 + t * w) / (w0 + w)
            weight[i] = w0 + w
            near = sdf.abs() < trunc
            j, wn = i[near], w[near]
            color[j] += view.image.reshape(-1, 3)[pix[near]].float() * wn[:, None]
            color_weight[j] += wn
        if progress is not None:
            progress()
    color /= color_weight.clamp(min=1e-12)[:, None]
    shape = tuple(int(x) for x in dims)
    return TSDFVolume(tsdf.reshape(shape), weight.reshape(shape), color.reshape(*shape, 3), lo, voxel)
