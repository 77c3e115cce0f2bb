"""Per-stage cost volume (spec 5): homography warping, group-wise correlation, entropy-based visibility
weighting of the source views; then regularisation and the depth head (spec 6, 7).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from mvsformerpp.geometry.warping import homography_warp, projection_4x4
from mvsformerpp.models.cvt import CostVolumeTransformer
from mvsformerpp.models.layers import ConvBnReLU
from mvsformerpp.models.regularization import CostRegNet, CostRegNet3D


def group_correlation(ref: torch.Tensor, warped: torch.Tensor, groups: int) -> torch.Tensor:
    """Mean over each channel group of ref * warped: [B,C,H,W] x [B,C,D,H,W] -> [B,G,D,H,W]."""
    B, C, D, H, W = warped.shape
    if groups == C:
        return ref[:, :, None] * warped
    return (ref.reshape(B, groups, C // groups, 1, H, W) * warped.reshape(B, groups, C // groups, D, H, W)).mean(2)


def matching_entropy(corr: torch.Tensor) -> torch.Tensor:
    """Entropy over depth of softmax(sum_g corr): [B,G,D,H,W] -> [B,1,H,W] (no gradient, as the reference)."""
    p = F.softmax(corr.sum(dim=1).detach(), dim=1)
    return (-p * torch.log(p + 1e-7)).sum(dim=1, keepdim=True)


def visibility_net() -> nn.Sequential:
    """Entropy map -> per-pixel visibility weight in (0, 1)."""
    return nn.Sequential(ConvBnReLU(1, 16), ConvBnReLU(16, 16), ConvBnReLU(16, 8), nn.Conv2d(8, 1, 1), nn.Sigmoid())


def depth_from_logits(logits: torch.Tensor, hypotheses: torch.Tensor, temperature: float | None):
    """Depth and confidence from [B,D,H,W] logits (spec 7).

    temperature None: argmax hypothesis (training); else sum_k softmax(t * logits)_k d_k.
    Confidence = max_k softmax(logits)_k (no temperature).
    """
    prob = F.softmax(logits, dim=1)
    if temperature is None:
        depth = torch.gather(hypotheses, 1, prob.argmax(dim=1, keepdim=True)).squeeze(1)
    else:
        depth = (F.softmax(logits * temperature, dim=1) * hypotheses).sum(dim=1)
    return depth, prob.max(dim=1)[0]


def visibility(vis: nn.Sequential, entropy: torch.Tensor) -> torch.Tensor:
    """Run the visibility net; in inference with channels-last weights, which oneDNN runs about twice
    as fast on these thin full-resolution maps (same numbers up to float rounding)."""
    if vis.training:
        return vis(entropy)
    cl = torch.channels_last
    x = entropy
    for layer in vis[:3]:
        x = F.conv2d(x, layer.conv.weight.contiguous(memory_format=cl), padding=1).contiguous(memory_format=cl)
        x = F.relu(F.batch_norm(x, layer.bn.running_mean, layer.bn.running_var, layer.bn.weight, layer.bn.bias,
                                False, 0.0, layer.bn.eps))
    return torch.sigmoid(vis[3](x)).contiguous()


class StageNet(nn.Module):
    """One cascade stage: cost volume, regulariser (CVT at stage 1, 3-D U-Nets after) and depth head."""

    def __init__(self, num_hypotheses: int, groups: int = 8, regularizer: str = "unet", cvt_kwargs=None):
        super().__init__()
        self.groups = groups
        self.vis = visibility_net()
        if regularizer == "cvt":
            self.cost_reg = CostVolumeTransformer(groups, **(cvt_kwargs or {}))
        elif num_hypotheses <= 8:
            self.cost_reg = CostRegNet3D(groups, groups)
        else:
            self.cost_reg = CostRegNet(groups, groups)

    def cost_volume(self, features: torch.Tensor, proj: torch.Tensor, hypotheses: torch.Tensor) -> torch.Tensor:
        """features [B,V,C,H,W], proj [B,V,2,4,4], hypotheses [B,D,H,W] -> [B,G,D,H,W] (fp32)."""
        with torch.autocast(device_type=features.device.type, enabled=False):
            ref = features[:, 0].float()
            ref_proj = projection_4x4(proj[:, 0, 0].float(), proj[:, 0, 1].float())
            volume_sum, vis_sum = 0.0, 0.0
            for v in range(1, features.shape[1]):
                src_proj = projection_4x4(proj[:, v, 0].float(), proj[:, v, 1].float())
                warped = homography_warp(features[:, v].float(), src_proj, ref_proj, hypotheses)
                corr = group_correlation(ref, warped, self.groups)
                weight = visibility(self.vis, matching_entropy(corr))  # [B,1,H,W]
                volume_sum = volume_sum + corr * weight[:, None]
                vis_sum = vis_sum + weight
            return volume_sum / (vis_sum[:, None] + 1e-6)

    def forward(self, features, proj, hypotheses, temperature: float | None, coords=None) -> dict:
        volume = self.cost_volume(features, proj, hypotheses)
        if isinstance(self.cost_reg, CostVolumeTransformer):
            logits = self.cost_reg(volume, coords)
        elif self.training and torch.is_grad_enabled():
            logits = checkpoint(self.cost_reg, volume, use_reentrant=False)  # memory, as the reference
        else:
            logits = self.cost_reg(volume)
        logits = logits.squeeze(1)
        depth, conf = depth_from_logits(logits, hypotheses, temperature)
        return {"depth": depth, "photometric_confidence": conf.detach(), "prob_volume_pre": logits,
                "depth_values": hypotheses}
