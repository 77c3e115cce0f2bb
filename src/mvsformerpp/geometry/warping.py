"""Homography warping of source features onto reference-view depth hypotheses (cost volume).

Convention (as the reference implementation): pixel (x, y) of the reference feature map is the
integer pixel index, with no +0.5 offset, and source coordinates are sampled with
``grid_sample(align_corners=True)``, so integer coordinates hit pixel values exactly.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


def projection_4x4(extrinsic: torch.Tensor, intrinsic: torch.Tensor) -> torch.Tensor:
    """Full-rank projection ``[K 0; 0 1] @ E`` from world-to-camera ``E`` [...,4,4] and ``K`` [...,3,3]."""
    proj = extrinsic.clone()
    proj[..., :3, :4] = intrinsic[..., :3, :3] @ extrinsic[..., :3, :4]
    return proj


def relative_projections(extrinsics: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """``[V-1, 3, 4]``: the top rows of ``P_v @ P_0^-1`` for the source views v = 1 .. V-1 of a view set, with
    ``P = [K 0; 0 1] @ E`` (:func:`projection_4x4`), computed in float64 from world-to-camera ``E`` [V, 4, 4]
    and intrinsics ``K`` [V, 3, 3] (pixel units, integer pixel coordinates). Row block ``[R | t]`` maps a
    reference pixel (x, y) at depth d to ``R [x, y, 1]^T d + t``, the source pixel times its depth: what the
    warp needs of the cameras, prepared outside a portable graph (which has no matrix inverse)."""
    E = np.asarray(extrinsics, dtype=np.float64)
    K = np.zeros((len(E), 4, 4))
    K[:, :3, :3] = np.asarray(intrinsics, dtype=np.float64)[:, :3, :3]
    K[:, 3, 3] = 1.0
    P = K @ E
    return (P[1:] @ np.linalg.inv(P[0]))[:, :3, :4]


def pixel_rays(relative: torch.Tensor, H: int, W: int):
    """``(R [x, y, 1]^T for every reference pixel [B, 3, H*W], t [B, 3, 1])`` of a relative projection
    ``relative`` [B, 3 or 4, 4] (float32; H, W may be symbolic sizes of an exported graph)."""
    rot, trans = relative[:, :3, :3], relative[:, :3, 3:4]
    y, x = torch.meshgrid(
        torch.arange(H, dtype=torch.float32, device=relative.device),
        torch.arange(W, dtype=torch.float32, device=relative.device),
        indexing="ij",
    )
    xyz = torch.stack((x.reshape(-1), y.reshape(-1), torch.ones_like(x).reshape(-1)))  # [3, HW]
    return rot @ xyz, trans


def warp_rays(src_proj: torch.Tensor, ref_proj: torch.Tensor, H: int, W: int):
    """The per-view part of the warp: :func:`pixel_rays` of the relative projection ``src_proj @ ref_proj^-1``;
    reusable for every hypothesis chunk."""
    with torch.autocast(device_type=src_proj.device.type, enabled=False):
        return pixel_rays(src_proj.float() @ torch.inverse(ref_proj.float()), H, W)


def homography_warp(
    src_feat: torch.Tensor,
    src_proj: torch.Tensor,
    ref_proj: torch.Tensor,
    depth_hypotheses: torch.Tensor,
    rays: tuple[torch.Tensor, torch.Tensor] | None = None,
    blocks: int = 1,
) -> torch.Tensor:
    """Sample source features at the projections of reference pixels lifted to each hypothesis depth.

    Args:
        src_feat: [B, C, H, W] source-view features.
        src_proj, ref_proj: [B, 4, 4] projections from :func:`projection_4x4` (intrinsics at the
            feature map's scale).
        depth_hypotheses: [B, D, H, W] z-depths in the reference camera, per reference pixel.
        rays: :func:`warp_rays` of these projections, when the caller warps in hypothesis chunks.
        blocks: for one image (B = 1) without autograd, split the D hypotheses into this many blocks
            of consecutive hypotheses, sampled as one batch: PyTorch's CPU ``grid_sample`` runs the
            images of a batch in parallel but one image on one thread, so with ``blocks`` = the number
            of threads the warp uses them all. D must be a multiple of ``blocks``; the source image is
            broadcast, not copied, and the values are those of ``blocks=1``.
    Returns:
        [B, C, D, H, W] warped source features, zeros where the projection leaves the image; with
        ``blocks`` > 1: [blocks, C, D / blocks, H, W], block k holding hypotheses k*D/blocks onwards.
    Computed in float32 whatever the caller's autocast (the reference disables autocast here).
    """
    B, C, H, W = src_feat.shape
    D = depth_hypotheses.shape[1]
    with torch.autocast(device_type=src_feat.device.type, enabled=False):
        src_feat = src_feat.float()
        depth = depth_hypotheses.float().reshape(B, 1, D, H * W)
        rot_xyz, trans = rays if rays is not None else warp_rays(src_proj, ref_proj, H, W)
        if depth.requires_grad or rot_xyz.requires_grad:  # differentiable form
            grid = sampling_grid(rot_xyz, trans, depth, H, W)
        else:  # the same numbers with fewer passes over the [B, D, H*W] grid
            grid = _sampling_grid(rot_xyz, trans, depth[:, 0], H, W)
        if blocks > 1:
            if B != 1 or D % blocks or grid.requires_grad or src_feat.requires_grad:
                raise ValueError(f"blocks={blocks} needs one image without autograd and a multiple of {blocks} "
                                 f"hypotheses (got B={B}, D={D})")
            warped = F.grid_sample(src_feat.expand(blocks, -1, -1, -1), grid.view(blocks, D * H // blocks, W, 2),
                                   mode="bilinear", padding_mode="zeros", align_corners=True)
            return warped.view(blocks, C, D // blocks, H, W)
        warped = F.grid_sample(src_feat, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    return warped.reshape(B, C, D, H, W)


def sampling_grid(rot_xyz: torch.Tensor, trans: torch.Tensor, depth: torch.Tensor, H: int, W: int) -> torch.Tensor:
    """grid_sample coordinates (x / z, y / z) normalised with align_corners=True, for points
    rot_xyz * depth + trans: rot_xyz [B, 3, HW], trans [B, 3, 1], depth [B, 1, D, HW] -> [B, D*H, W, 2]
    (the differentiable form, without in-place operations)."""
    B, D = depth.shape[0], depth.shape[2]
    pts = rot_xyz.unsqueeze(2) * depth + trans.reshape(B, 3, 1, 1)
    xy = pts[:, :2] / (pts[:, 2:3] + 1e-6)  # [B, 2, D, HW]
    gx = xy[:, 0] / ((W - 1) / 2) - 1
    gy = xy[:, 1] / ((H - 1) / 2) - 1
    return torch.stack((gx, gy), dim=3).reshape(B, D * H, W, 2)


def _sampling_grid(rot_xyz: torch.Tensor, trans: torch.Tensor, depth: torch.Tensor, H: int, W: int):
    """grid_sample coordinates (x / z, y / z) normalised with align_corners=True, for points
    rot_xyz * depth + trans: rot_xyz [B, 3, HW], trans [B, 3, 1], depth [B, D, HW] -> [B, D*H, W, 2].
    The same operations in the same order as the differentiable form (bit-identical), in place."""
    B, D, HW = depth.shape
    z = torch.mul(rot_xyz[:, 2:3], depth).add_(trans[:, 2:3]).add_(1e-6)  # [B, D, HW]
    grid = depth.new_empty(B, D, HW, 2)
    for i, size in ((0, W), (1, H)):
        coord = torch.mul(rot_xyz[:, i:i + 1], depth).add_(trans[:, i:i + 1]).div_(z)
        torch.div(coord, (size - 1) / 2, out=grid[..., i]).sub_(1)
    return grid.reshape(B, D * H, W, 2)
