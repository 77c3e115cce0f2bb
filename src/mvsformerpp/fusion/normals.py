"""Surface normals from depth maps, for the fused cloud (Poisson meshing and viewers use them).

A depth map's normal at a pixel is the cross product of the central differences of its back-projected
neighbours (pixel centres, :func:`mvsformerpp.geometry.camera.depth_to_points`), turned towards the camera;
pixels at a depth edge (neighbours more than ``edge`` relative depth apart) or next to a missing depth
get none. A fused point takes the normal and the confidence of its pixel in the reference view that produced it
(the confidence is what fusion's threshold and a viewer's confidence slider filter on).
"""

from __future__ import annotations

from collections.abc import Sequence

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


class ReferenceAttributes:
    """Normal and confidence of fused points from the reference view that produced them.

    ``attrs(r, xyz)`` projects points of reference view ``r`` into it and reads its normal map (turned to
    world coordinates, facing that camera) and confidence at their pixels; the normal map of the current
    reference is kept, so a stream of fused pieces costs one normal map per view.
    """

    def __init__(self, views: Sequence[FusionView]):
        self.views = views
        self._r: int | None = None
        self._normals: torch.Tensor | None = None

    def __call__(self, r: int, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ref = self.views[r]
        if r != self._r:
            self._normals = normal_map(ref.depth, ref.K) @ ref.E[:3, :3].float()  # camera -> world, row form
            self._r = r
        H, W = ref.depth.shape
        X = torch.as_tensor(xyz, dtype=torch.float32, device=ref.depth.device)
        u, v, _ = project(ref.K.float(), ref.E.float(), X)
        ui, vi = u.clamp(0, W - 1).long(), v.clamp(0, H - 1).long()
        return self._normals[vi, ui].cpu().numpy(), ref.confidence[vi, ui].float().cpu().numpy()
