"""3-D U-Nets regularising the cost volumes of stages 2-4 (spec 6.2, 6.3)."""

from __future__ import annotations

import torch
from torch import nn

from mvsformerpp.models.layers import ConvBnReLU3d, DeconvBnReLU3d


class CostRegNet(nn.Module):
    """Stage 2: U-Net with stride 2 in depth and space; logits [B, 1, D, H, W]."""

    def __init__(self, cin: int = 8, base: int = 8):
        super().__init__()
        self.conv1 = ConvBnReLU3d(cin, base * 2, stride=2)
        self.conv2 = ConvBnReLU3d(base * 2, base * 2)
        self.conv3 = ConvBnReLU3d(base * 2, base * 4, stride=2)
        self.conv4 = ConvBnReLU3d(base * 4, base * 4)
        self.conv5 = ConvBnReLU3d(base * 4, base * 8, stride=2)
        self.conv6 = ConvBnReLU3d(base * 8, base * 8)
        self.conv7 = DeconvBnReLU3d(base * 8, base * 4)
        self.conv9 = DeconvBnReLU3d(base * 4, base * 2)
        self.conv11 = DeconvBnReLU3d(base * 2, base)
        self.prob = nn.Conv3d(base, 1, 3, padding=1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        c2 = self.conv2(self.conv1(x))
        c4 = self.conv4(self.conv3(c2))
        y = self.conv6(self.conv5(c4))
        y = c4 + self.conv7(y)
        y = c2 + self.conv9(y)
        y = x + self.conv11(y)
        return self.prob(y)


def _deconv_hw(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.ConvTranspose3d(cin, cout, 3, stride=(1, 2, 2), padding=1, output_padding=(0, 1, 1), bias=False),
        nn.BatchNorm3d(cout),
        nn.ReLU(inplace=True),
    )


class CostRegNet3D(nn.Module):
    """Stages 3-4: U-Net that keeps the depth axis (stride (1,2,2)); logits [B, 1, D, H, W]."""

    def __init__(self, cin: int = 8, base: int = 8):
        super().__init__()
        s = (1, 2, 2)
        self.conv1 = ConvBnReLU3d(cin, base * 2, stride=s)
        self.conv2 = ConvBnReLU3d(base * 2, base * 2)
        self.conv3 = ConvBnReLU3d(base * 2, base * 4, stride=s)
        self.conv4 = ConvBnReLU3d(base * 4, base * 4)
        self.conv5 = ConvBnReLU3d(base * 4, base * 8, stride=s)
        self.conv6 = ConvBnReLU3d(base * 8, base * 8)
        self.conv7 = _deconv_hw(base * 8, base * 4)
        self.conv9 = _deconv_hw(base * 4, base * 2)
        self.conv11 = _deconv_hw(base * 2, base)
        self.prob = nn.Conv3d(base, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        c2 = self.conv2(self.conv1(x))
        c4 = self.conv4(self.conv3(c2))
        y = self.conv6(self.conv5(c4))
        y = c4 + self.conv7(y)
        y = c2 + self.conv9(y)
        y = x + self.conv11(y)
        return self.prob(y)
