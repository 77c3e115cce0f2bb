"""CNN feature pyramid (spec 1): an encoder down to 1/8 and a decoder back to full resolution."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models.layers import ConvBnLeakyReLU, Swish


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
        conv01 = self.conv01(self.conv00(x))
        conv11 = self.conv11(self.conv10(self.downsample1(conv01)))
        conv21 = self.conv21(self.conv20(self.downsample2(conv11)))
        conv31 = self.conv31(self.conv30(self.downsample3(conv21)))
        return conv01, conv11, conv21, conv31


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
        out0 = self.out0(conv31)
        t1 = _up2(conv31) + self.inner1(conv21)
        out1 = self.out1(t1)
        t2 = _up2(t1) + self.inner2(conv11)
        out2 = self.out2(t2)
        if self.training:
            out3 = self.out3(_up2(t2) + self.inner3(conv01))
        else:
            out3 = self.out3[2](self.out3[1](self._last_level_conv(t2, conv01)))
        return [out0, out1, out2, out3]

    def _last_level_conv(self, t2: torch.Tensor, conv01: torch.Tensor) -> torch.Tensor:
        """Conv3x3(up2(t2) + inner3(conv01)) without the 64-channel full-resolution sum.

        By linearity it is Conv3x3(up2(t2)) + Conv3x3'(conv01) + B, where Conv3x3' = Conv3x3 o inner3
        (a 3x3 conv from c0 to c0 channels) and B is inner3's bias seen through the zero-padded 3x3
        conv (constant inside, smaller at the border). The same numbers up to float rounding, about
        half the memory traffic at full resolution.
        """
        conv, inner = self.out3[0], self.inner3
        w_fold = torch.einsum("ocij,ck->okij", conv.weight, inner.weight[:, :, 0, 0])
        w_bias = torch.einsum("ocij,c->oij", conv.weight, inner.bias)[:, None]
        ones = conv01.new_ones(1, 1, *conv01.shape[-2:])
        bias_map = F.conv2d(ones, w_bias, padding=1)
        # Channels-last for the one 64-channel full-resolution convolution: faster in oneDNN.
        up = _up2(t2.contiguous(memory_format=torch.channels_last))
        return conv(up).contiguous() + F.conv2d(conv01, w_fold, padding=1) + bias_map
