"""Surface normals from depth maps, for the fused cloud (Poisson meshing and viewers use them).

A depth map's normal at a pixel is the cross product of the central differences of its back-projected
neighbours (pixel centres, :func:`mvsformerpp.geometry.camera.depth_to_points`), turned towards the camera;
pixels at a depth edge (neighbours more than ``edge`` relative depth apart) or next to a missing depth
get none. A fused point takes the normalised sum of the normals of the views whose depth map sees it
(projected depth within ``tolerance`` relative of the map's depth there), and the mean confidence of
those views' pixels (what a viewer's confidence slider filters on).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.fusion.core import FusionView
from mvsformerpp.geometry.camera import depth_to_points, project


def normal_map(depth: torch.Tensor, K: torch.Tensor, edge: float = 0.05) -> torch.Tensor:
    """Camera-frame unit normals ``[H, W, 3]`` of a depth map (0 = none), facing the camera; zeros where unknown."""
    X = depth_to_points(depth.float(), K.float(), torch.eye(4, device=depth.device))
    P = F.pad(X.permute(2, 0, 1)[None], (1, 1, 1, 1), mode="replicate")[0].permute(1, 2, 0)
    D = F.pad(depth[None, None].float(), (1, 1, 1, 1), mode="constant")[0, 0]
    du, dv = P[1:-1, 2:] - P[1:-1, :-2], P[2:, 1:-1] - P[:-2, 1:-1]
    n = torch.cross(du, dv, dim=-1)
    n = n * torch.where((n * X).sum(-1, keepdim=True) > 0, -1.0, 1.0)  # towards the camera
    near = torch.stack([D[1:-1, 2:], D[1:-1, :-2], D[2:, 1:-1], D[:-2, 1:-1]])
    d = depth.float()
    ok = (d > 0) & (near > 0).all(0) & ((near - d).abs() <= edge * d).all(0)
    norm = n.norm(dim=-1, keepdim=True)
    ok &= norm[..., 0] > 0
    return torch.where(ok[..., None], n / norm.clamp(min=1e-30), torch.zeros_like(n))


def point_attributes(points: np.ndarray, views: Iterable[FusionView], tolerance: float = 0.01,
                     chunk: int = 1 << 21) -> tuple[np.ndarray, np.ndarray]:
    """World-frame unit normals ``[N, 3]`` and mean confidences ``[N]`` (float32) of fused points from the
    views that see them (zeros where none does). ``views`` is iterated once (a generator may load them)."""
    acc = torch.zeros((len(points), 3), dtype=torch.float32)
    conf_sum = torch.zeros(len(points), dtype=torch.float32)
    seen_count = torch.zeros(len(points), dtype=torch.float32)
    with torch.no_grad():
        for view in views:
            device = view.depth.device
            nmap = normal_map(view.depth, view.K)
            world = nmap @ view.E[:3, :3].float()  # camera -> world: R^T n, row-vector form
            H, W = view.depth.shape
            for s in range(0, len(points), chunk):
                X = torch.as_tensor(points[s:s + chunk], dtype=torch.float32, device=device)
                u, v, z = project(view.K.float(), view.E.float(), X)
                inside = (u >= 0) & (u < W) & (v >= 0) & (v < H) & (z > 0)
                ui, vi = u.clamp(0, W - 1).long(), v.clamp(0, H - 1).long()
                d = view.depth[vi, ui]
                seen = inside & (d > 0) & ((d - z).abs() <= tolerance * d)
                acc[s:s + chunk] += (world[vi, ui] * seen[:, None]).cpu()
                conf_sum[s:s + chunk] += (view.confidence[vi, ui] * seen).cpu()
                seen_count[s:s + chunk] += seen.cpu()
    norm = acc.norm(dim=1, keepdim=True)
    normals = torch.where(norm > 0, acc / norm.clamp(min=1e-30), torch.zeros_like(acc))
    return normals.numpy(), (conf_sum / seen_count.clamp(min=1)).numpy()

