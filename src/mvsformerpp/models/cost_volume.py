"""Per-stage cost volume: homography warping, group-wise correlation, entropy-based visibility
weighting of the source views; then regularisation and the depth head.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint

from mvsformerpp.geometry.warping import homography_warp, projection_4x4, warp_rays
from mvsformerpp.models import prepared
from mvsformerpp.models.cvt import CostVolumeTransformer
from mvsformerpp.models.layers import ConvBnReLU
from mvsformerpp.models.prepared import fused_conv_bn
from mvsformerpp.models.regularization import CostRegNet, CostRegNet3D


def group_correlation(ref: torch.Tensor, warped: torch.Tensor, groups: int, out: torch.Tensor | None = None):
    """Mean over each channel group of ref * warped: [B,C,H,W] x [B,C,D,H,W] -> [B,G,D,H,W] (into out)."""
    B, C, D, H, W = warped.shape
    if groups == C:
        return torch.mul(ref[:, :, None], warped, out=out)
    cg = C // groups
    r, w = ref.reshape(B, groups, cg, 1, H, W), warped.reshape(B, groups, cg, D, H, W)
    if out is None:
        return torch.mean(r * w, 2)
    # accumulate channel by channel into out (no [B, C, D, H, W] product; no autograd)
    torch.mul(r[:, :, 0], w[:, :, 0], out=out)
    for c in range(1, cg):
        out.addcmul_(r[:, :, c], w[:, :, c])
    return out.mul_(1.0 / cg)


def matching_entropy(corr: torch.Tensor) -> torch.Tensor:
    """Entropy over depth of softmax(sum_g corr): [B,G,D,H,W] -> [B,1,H,W] (no gradient, as the reference)."""
    p = F.softmax(corr.sum(dim=1).detach(), dim=1)
    return (-p * torch.log(p + 1e-7)).sum(dim=1, keepdim=True)


def visibility_net() -> nn.Sequential:
    """Entropy map -> per-pixel visibility weight in (0, 1)."""
    return nn.Sequential(ConvBnReLU(1, 16), ConvBnReLU(16, 16), ConvBnReLU(16, 8), nn.Conv2d(8, 1, 1), nn.Sigmoid())


def depth_from_logits(logits: torch.Tensor, hypotheses: torch.Tensor, temperature: float | None):
    """Depth and confidence from [B,D,H,W] logits.

    temperature None: argmax hypothesis (training); else sum_k softmax(t * logits)_k d_k.
    Confidence = max_k softmax(logits)_k (no temperature).
    """
    prob = F.softmax(logits, dim=1)
    if temperature is None:
        depth = torch.gather(hypotheses, 1, prob.argmax(dim=1, keepdim=True)).squeeze(1)
    else:
        depth = (F.softmax(logits * temperature, dim=1) * hypotheses).sum(dim=1)
    return depth, prob.max(dim=1)[0]


def visibility(vis: nn.Sequential, entropy: torch.Tensor, forms: list | None = None) -> torch.Tensor:
    """Run the visibility net; with its prepared ``forms`` (:meth:`StageNet.build_inference_forms`),
    each conv-BatchNorm-ReLU is one convolution with the BatchNorm folded in and an in-place ReLU, on
    channels-last maps, which oneDNN runs about twice as fast at these thin full-resolution sizes."""
    if forms is None:
        return vis(entropy)
    # A one-channel map is both NCHW and NHWC, and oneDNN then takes a slow NCHW kernel for the first
    # convolution; a zero second channel (with zero weights) makes the input unambiguously NHWC.
    B, _, H, W = entropy.shape
    x = entropy.new_zeros(B, H, W, 2)
    x[..., 0] = entropy[:, 0]
    x = x.permute(0, 3, 1, 2)
    for w, b in forms:
        x = F.conv2d(x.contiguous(memory_format=torch.channels_last), w, b, padding=1).relu_()
    return vis[3](x).sigmoid_().contiguous()


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
            ref = features[:, 0].float().contiguous()
            ref_proj = projection_4x4(proj[:, 0, 0].float(), proj[:, 0, 1].float())
            B, C, H, W = ref.shape
            D = hypotheses.shape[1]
            # Hypotheses in chunks bound the warped-feature memory (full resolution: ~0.25 GB per view).
            step = max(1, min(D, (1 << 24) // max(1, B * C * H * W)))
            inplace = prepared.lean()  # eval without autograd: reuse buffers
            blocks = 1
            if inplace and B == 1:  # one image: its warp in blocks of hypotheses, one per thread (a chunk
                # then holds at least `blocks` hypotheses, so at most `blocks` times the budget above)
                blocks = max(k for k in range(1, min(torch.get_num_threads(), D) + 1) if D % k == 0)
                step = max(step // blocks, 1) * blocks
            vis_forms = prepared.forms(self)
            volume_sum, vis_sum, spare = None, 0.0, None
            for v in range(1, features.shape[1]):
                src_proj = projection_4x4(proj[:, v, 0].float(), proj[:, v, 1].float())
                src = features[:, v].float()
                if inplace:  # eval without autograd: channels-last rows for the warp's gathers (the same values)
                    src = src.contiguous(memory_format=torch.channels_last)
                rays = warp_rays(src_proj, ref_proj, H, W)
                corr = spare if spare is not None else ref.new_empty(B, self.groups, D, H, W)
                for d in range(0, D, step):
                    chunk = hypotheses[:, d:d + step]
                    if inplace and blocks > 1 and chunk.shape[1] % blocks == 0:  # B = 1: block k is [1, ...]
                        warped = homography_warp(src, src_proj, ref_proj, chunk, rays, blocks=blocks)
                        n = chunk.shape[1] // blocks
                        for k in range(blocks):
                            group_correlation(ref, warped[k:k + 1], self.groups,
                                              out=corr[:, :, d + k * n:d + (k + 1) * n])
                    elif inplace:
                        warped = homography_warp(src, src_proj, ref_proj, chunk, rays)
                        group_correlation(ref, warped, self.groups, out=corr[:, :, d:d + step])
                    else:
                        warped = homography_warp(src, src_proj, ref_proj, chunk, rays)
                        corr[:, :, d:d + step] = group_correlation(ref, warped, self.groups)
                    del warped
                weight = visibility(self.vis, matching_entropy(corr), vis_forms)  # [B,1,H,W]
                if volume_sum is None:
                    volume_sum = corr.mul_(weight[:, None]) if inplace else corr * weight[:, None]
                else:
                    volume_sum.addcmul_(corr, weight[:, None])
                    spare = corr if inplace else None
                vis_sum = vis_sum + weight
                del corr
            if inplace:
                return volume_sum.div_(vis_sum[:, None].add_(1e-6))
            return volume_sum / (vis_sum[:, None] + 1e-6)

    inference_sources = ("vis",)

    def build_inference_forms(self) -> list:
        """The visibility net's conv-BatchNorm pairs folded, channels-last; the first one reads a zero
        second input channel (see :func:`visibility`)."""
        forms = [fused_conv_bn(layer.conv, layer.bn) for layer in self.vis[:3]]
        w, b = forms[0]
        forms[0] = (torch.cat([w, torch.zeros_like(w)], 1).contiguous(memory_format=torch.channels_last), b)
        return forms

    def forward(self, features, proj, hypotheses, temperature: float | None, coords=None) -> dict:
        return self.predict(self.cost_volume(features, proj, hypotheses), hypotheses, temperature, coords)

    def predict(self, volume: torch.Tensor, hypotheses: torch.Tensor, temperature: float | None,
                coords=None) -> dict:
        """Regularise a cost volume [B,G,D,H,W] into logits and read out depth and confidence."""
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
