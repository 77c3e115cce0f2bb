"""Homography warping of source features onto reference-view depth hypotheses (cost volume).

Convention (as the reference implementation): pixel (x, y) of the reference feature map is the
integer pixel index, with no +0.5 offset, and source coordinates are sampled with
``grid_sample(align_corners=True)``, so integer coordinates hit pixel values exactly.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


def projection_4x4(extrinsic: torch.Tensor, intrinsic: torch.Tensor) -> torch.Tensor:
    """Full-rank projection ``[K 0; 0 1] @ E`` from world-to-camera ``E`` [...,4,4] and ``K`` [...,3,3]."""
    proj = extrinsic.clone()
    proj[..., :3, :4] = intrinsic[..., :3, :3] @ extrinsic[..., :3, :4]
    return proj


def homography_warp(
    src_feat: torch.Tensor,
    src_proj: torch.Tensor,
    ref_proj: torch.Tensor,
    depth_hypotheses: torch.Tensor,
) -> torch.Tensor:
    """Sample source features at the projections of reference pixels lifted to each hypothesis depth.

    Args:
        src_feat: [B, C, H, W] source-view features.
        src_proj, ref_proj: [B, 4, 4] projections from :func:`projection_4x4` (intrinsics at the
            feature map's scale).
        depth_hypotheses: [B, D, H, W] z-depths in the reference camera, per reference pixel.
    Returns:
        [B, C, D, H, W] warped source features; zeros where the projection leaves the image.
    Computed in float32 whatever the caller's autocast (the reference disables autocast here).
    """
    B, C, H, W = src_feat.shape
    D = depth_hypotheses.shape[1]
    device_type = src_feat.device.type
    with torch.autocast(device_type=device_type, enabled=False):
        src_feat = src_feat.float()
        depth = depth_hypotheses.float()
        proj = src_proj.float() @ torch.inverse(ref_proj.float())
        rot, trans = proj[:, :3, :3], proj[:, :3, 3:4]
        y, x = torch.meshgrid(
            torch.arange(H, dtype=torch.float32, device=src_feat.device),
            torch.arange(W, dtype=torch.float32, device=src_feat.device),
            indexing="ij",
        )
        xyz = torch.stack((x.reshape(-1), y.reshape(-1), torch.ones_like(x).reshape(-1)))  # [3, HW]
        rot_xyz = rot @ xyz  # [B, 3, HW]
        pts = rot_xyz.unsqueeze(2) * depth.reshape(B, 1, D, H * W) + trans.reshape(B, 3, 1, 1)
        xy = pts[:, :2] / (pts[:, 2:3] + 1e-6)  # [B, 2, D, HW]
        gx = xy[:, 0] / ((W - 1) / 2) - 1
        gy = xy[:, 1] / ((H - 1) / 2) - 1
        grid = torch.stack((gx, gy), dim=3).reshape(B, D * H, W, 2)
        warped = F.grid_sample(src_feat, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    return warped.reshape(B, C, D, H, W)
