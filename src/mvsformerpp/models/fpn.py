"""CNN feature pyramid (spec 1): an encoder down to 1/8 and a decoder back to full resolution."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models.layers import ConvBnLeakyReLU, Swish, fold_batchnorm


class FPNEncoder(nn.Module):
    """[N,3,H,W] -> (conv01 [N,c0,H,W], conv11 [N,c1,H/2,W/2], conv21 [N,c2,H/4,W/4], conv31 [N,c3,H/8,W/8])."""

    def __init__(self, feat_chs=(8, 16, 32, 64)):
        super().__init__()
        c0, c1, c2, c3 = feat_chs
        self.conv00 = ConvBnLeakyReLU(3, c0, 7, 1, 3)
        self.conv01 = ConvBnLeakyReLU(c0, c0, 5, 1, 2)
        self.downsample1 = ConvBnLeakyReLU(c0, c1, 5, 2, 2)
        self.conv10 = ConvBnLeakyReLU(c1, c1, 3, 1, 1)
        self.conv11 = ConvBnLeakyReLU(c1, c1, 3, 1, 1)
        self.downsample2 = ConvBnLeakyReLU(c1, c2, 5, 2, 2)
        self.conv20 = ConvBnLeakyReLU(c2, c2, 3, 1, 1)
        self.conv21 = ConvBnLeakyReLU(c2, c2, 3, 1, 1)
        self.downsample3 = ConvBnLeakyReLU(c2, c3, 3, 2, 1)
        self.conv30 = ConvBnLeakyReLU(c3, c3, 3, 1, 1)
        self.conv31 = ConvBnLeakyReLU(c3, c3, 3, 1, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if self.training or torch.is_grad_enabled():
            block = _call
        else:  # inference: BatchNorm folded, in-place activation, channels-last (same numbers)
            block = _conv_bn_leaky_inference
        conv01 = block(self.conv01, block(self.conv00, x))
        conv11 = block(self.conv11, block(self.conv10, block(self.downsample1, conv01)))
        conv21 = block(self.conv21, block(self.conv20, block(self.downsample2, conv11)))
        conv31 = block(self.conv31, block(self.conv30, block(self.downsample3, conv21)))
        return conv01, conv11, conv21, conv31


def _call(module: nn.Module, x: torch.Tensor) -> torch.Tensor:
    return module(x)


# Inference (eval, no autograd) runs the pyramid in channels-last memory, where oneDNN's thin
# convolutions at full resolution are about twice as fast, with each eval BatchNorm folded into its
# convolution and activations in place: the same function up to float rounding.
_CL = torch.channels_last


def _conv_inference(x: torch.Tensor, conv: nn.Conv2d, bn: nn.Module | None = None) -> torch.Tensor:
    """conv(x), then bn if given, as one channels-last convolution."""
    if bn is None:
        w, b = conv.weight, conv.bias
    else:
        w, b = fold_batchnorm(conv.weight, bn, bias=conv.bias)
    return F.conv2d(x.contiguous(memory_format=_CL), w.contiguous(memory_format=_CL), b, conv.stride, conv.padding)


def _conv_bn_leaky_inference(block: ConvBnLeakyReLU, x: torch.Tensor) -> torch.Tensor:
    return F.leaky_relu_(_conv_inference(x, block.conv, block.bn), 0.1)


def _out_block_inference(block: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    y = _conv_inference(x, block[0], block[1])
    return y.mul_(torch.sigmoid(y))  # Swish


def _up2(x: torch.Tensor) -> torch.Tensor:
    # The reference upsamples in fp32 with align_corners=True here (spec 12).
    return F.interpolate(x.float(), scale_factor=2, mode="bilinear", align_corners=True)


class FPNDecoder(nn.Module):
    """Top-down pathway: per-stage features with c3, c2, c1, c0 channels at 1/8 ... 1/1 (spec 1)."""

    def __init__(self, feat_chs=(8, 16, 32, 64)):
        super().__init__()
        c0, c1, c2, c3 = feat_chs

        def out_block(cin, cout, k):
            return nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2), nn.BatchNorm2d(cout), Swish())

        self.out0 = out_block(c3, c3, 1)
        self.inner1 = nn.Conv2d(c2, c3, 1)
        self.out1 = out_block(c3, c2, 3)
        self.inner2 = nn.Conv2d(c1, c3, 1)
        self.out2 = out_block(c3, c1, 3)
        self.inner3 = nn.Conv2d(c0, c3, 1)
        self.out3 = out_block(c3, c0, 3)

    def forward(self, conv01, conv11, conv21, conv31) -> list[torch.Tensor]:
        if not (self.training or torch.is_grad_enabled()):
            return self._forward_inference(conv01, conv11, conv21, conv31)
        out0 = self.out0(conv31)
        t1 = _up2(conv31) + self.inner1(conv21)
        out1 = self.out1(t1)
        t2 = _up2(t1) + self.inner2(conv11)
        out2 = self.out2(t2)
        out3 = self.out3(_up2(t2) + self.inner3(conv01))
        return [out0, out1, out2, out3]

    def _forward_inference(self, conv01, conv11, conv21, conv31) -> list[torch.Tensor]:
        """forward in channels-last memory with in-place sums (see _conv_inference)."""
        conv31 = conv31.contiguous(memory_format=_CL)
        out0 = _out_block_inference(self.out0, conv31)
        t1 = _up2(conv31).add_(_conv_inference(conv21, self.inner1))
        out1 = _out_block_inference(self.out1, t1)
        t2 = _up2(t1).add_(_conv_inference(conv11, self.inner2))
        del t1
        out2 = _out_block_inference(self.out2, t2)
        return [out0, out1, out2, self._last_level_inference(t2, conv01)]

    def _last_level_inference(self, t2: torch.Tensor, conv01: torch.Tensor, band_bytes: int = 1 << 24):
        """out3(up2(t2) + inner3(conv01)) in row bands, without any 64-channel full-resolution map.

        By linearity, Conv3x3(up2(t2) + inner3(conv01)) = Conv3x3(up2(t2) + b_inner) + Conv3x3'(conv01)
        with Conv3x3' = Conv3x3 o inner3 (c0 -> c0 channels), both zero-padded at the image border. The
        second term is one thin convolution over the whole image; the first runs in bands of output
        rows, each needing its input rows and one halo row either side, whose upsampling is computed
        directly (separable bilinear, align_corners=True). The eval BatchNorm is folded in and Swish
        runs in place. The same numbers up to float rounding, a bounded working set.
        """
        conv, bn, inner = self.out3[0], self.out3[1], self.inner3
        w_fold = torch.einsum("ocij,ck->okij", conv.weight, inner.weight[:, :, 0, 0])
        w, b = fold_batchnorm(torch.cat([conv.weight, w_fold], 1), bn, bias=conv.bias)
        cl = torch.channels_last  # oneDNN runs these thin full-resolution convolutions fastest in NHWC
        w_up = w[:, : conv.in_channels].contiguous(memory_format=cl)
        w_low = w[:, conv.in_channels:].contiguous(memory_format=cl)
        out = F.conv2d(conv01.float().contiguous(memory_format=cl), w_low, b, padding=1)
        t2 = t2.float().permute(0, 2, 3, 1).contiguous()  # NHWC rows: cheap to gather and interpolate
        N, _, H, W = out.shape
        rows = max(4, band_bytes // (4 * w_up.shape[1] * W))
        for r0 in range(0, H, rows):
            r1 = min(H, r0 + rows)
            a, z = max(r0 - 1, 0), min(r1 + 1, H)
            up = _up2_rows_nhwc(t2, a, z, H, W).add_(inner.bias.view(1, -1, 1, 1))
            # zero padding is right at the image border; elsewhere the halo rows are real and the
            # padded output rows are dropped
            band = out[:, :, r0:r1].add_(F.conv2d(up, w_up, padding=1)[:, :, r0 - a:r1 - a])
            band.mul_(torch.sigmoid(band))
        return out


def _up2_rows_nhwc(x: torch.Tensor, a: int, z: int, H: int, W: int) -> torch.Tensor:
    """Rows a..z-1 of F.interpolate(x, (H, W), mode="bilinear", align_corners=True) for x given as
    NHWC [N, h, w, C]; the result is [N, C, z-a, W] in channels-last memory."""
    h = x.shape[1]
    scale = (h - 1) / (H - 1) if H > 1 else 0.0
    ys = torch.arange(a, z, dtype=torch.float32, device=x.device) * scale
    y0 = ys.floor().long().clamp_(max=h - 1)
    y1 = (y0 + 1).clamp_(max=h - 1)
    fy = (ys - y0).view(-1, 1, 1)
    rows = (x[:, y0] * (1 - fy)).add_(x[:, y1] * fy).permute(0, 3, 1, 2)
    return F.interpolate(rows, (z - a, W), mode="bilinear", align_corners=True)
