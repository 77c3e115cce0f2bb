"""Small building blocks shared by the network modules.

Attribute names (``conv``, ``bn``, ``fc1``, ``gamma``, ...) follow the reference implementation so
that official checkpoints load with ``strict=True``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models import prepared


class ConvBnLeakyReLU(nn.Module):
    """Conv2d (no bias) -> BatchNorm2d -> LeakyReLU(0.1): the FPN encoder block."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, padding: int = 0):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(cout, momentum=0.1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.leaky_relu(self.bn(self.conv(x)), 0.1, inplace=True)


class ConvBnReLU(nn.Module):
    """Conv2d 3x3 (no bias) -> BatchNorm2d -> ReLU (visibility networks)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1, padding: int = 1):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, kernel, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)), inplace=True)


class ConvBnReLU3d(nn.Module):
    """Conv3d (no bias) -> BatchNorm3d -> ReLU (3-D U-Nets)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride=1, padding: int = 1):
        super().__init__()
        self.conv = nn.Conv3d(cin, cout, kernel, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm3d(cout, momentum=0.1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)), inplace=True)


class DeconvBnReLU3d(nn.Module):
    """ConvTranspose3d (no bias) -> BatchNorm3d -> ReLU (stage-2 U-Net decoder)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride=2, padding: int = 1, output_padding=1):
        super().__init__()
        self.conv = nn.ConvTranspose3d(
            cin, cout, kernel, stride=stride, padding=padding, output_padding=output_padding, bias=False
        )
        self.bn = nn.BatchNorm3d(cout, momentum=0.1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)), inplace=True)


class Swish(nn.Module):
    """x * sigmoid(x)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * torch.sigmoid(x)


class Mlp(nn.Module):
    """Linear -> GELU -> Linear (transformer feed-forward)."""

    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(gelu_(self.fc1(x)))


def gelu_(x: torch.Tensor) -> torch.Tensor:
    """GELU (exact, erf form); in place in a forward without autograd (:func:`.prepared.lean`), which
    spares a large allocation per transformer block."""
    if not prepared.lean():
        return F.gelu(x)
    return torch.ops.aten.gelu_(x)


class LayerScale(nn.Module):
    """Per-channel learnable scale (DINOv2's LayerScale; the paper's ALS in SVA)."""

    def __init__(self, dim: int, init_value: float = 1.0):
        super().__init__()
        self.gamma = nn.Parameter(torch.full((dim,), float(init_value)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.gamma

    def residual(self, x: torch.Tensor, branch: torch.Tensor) -> torch.Tensor:
        """x + self(branch); in a forward without autograd in one pass (addcmul), sparing the scaled
        branch."""
        if not prepared.lean():
            return x + self(branch)
        return torch.addcmul(x, branch, self.gamma)


class LayerNorm3D(nn.Module):
    """Channel-wise LayerNorm of a [B, C, D, H, W] volume (CVT patchify/unpatchify)."""

    def __init__(self, channels: int, eps: float = 1e-6):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        u = x.mean(1, keepdim=True)
        s = (x - u).pow(2).mean(1, keepdim=True)
        x = (x - u) / torch.sqrt(s + self.eps)
        return self.weight[:, None, None, None] * x + self.bias[:, None, None, None]
