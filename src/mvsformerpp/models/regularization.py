"""3-D U-Nets regularising the cost volumes of stages 2-4 (spec 6.2, 6.3)."""

from __future__ import annotations

import torch
from torch import nn

from mvsformerpp.models.layers import ConvBnReLU3d, DeconvBnReLU3d


def _unet_forward(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """The U-Net both regularisers share: three strided levels, additive skips, a logit head."""
    c2 = net.conv2(net.conv1(x))
    c4 = net.conv4(net.conv3(c2))
    y = net.conv6(net.conv5(c4))
    y = c4 + net.conv7(y)
    y = c2 + net.conv9(y)
    y = x + net.conv11(y)
    return net.prob(y)


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
        return _unet_forward(self, x)


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
        if not self.training and x.device.type == "cpu":
            return _fast_forward_3d(self, x)  # the same function, faster on CPU (see below)
        return _unet_forward(self, x)


# ------------------------------------------------------------------------------------------------
# Inference fast path for the depth-preserving U-Net (stages 3-4, D = 8 or 4 hypotheses).
# A 3-D convolution whose depth kernel is 3 (padding 1, stride 1 in depth) equals a 2-D convolution
# over channels (c, d) with a depth-banded weight: W2[(o, d'), (c, d)] = W[o, c, d - d' + 1] for
# |d - d'| <= 1. oneDNN runs these wider 2-D convolutions several times faster than the thin 3-D ones;
# the result is the same up to float summation order.

_band_cache: dict = {}


def _banded(weight: torch.Tensor, D: int, transposed: bool) -> torch.Tensor:
    key = (weight.data_ptr(), weight._version, D, transposed, weight.device, weight.dtype)
    if key not in _band_cache:
        if len(_band_cache) > 64:
            _band_cache.clear()
        a, b, _, kh, kw = weight.shape  # conv: [out, in, 3, kh, kw]; transposed: [in, out, 3, kh, kw]
        W2 = weight.new_zeros(a, D, b, D, kh, kw)
        for d_out in range(D):
            for k in range(3):
                d_in = d_out + k - 1
                if 0 <= d_in < D:
                    if transposed:  # out[d'] += in[d] w[d' - d + 1]: index by (in=d, out=d')
                        W2[:, d_in, :, d_out] = weight[:, :, 2 - k]
                    else:
                        W2[:, d_out, :, d_in] = weight[:, :, k]
        _band_cache[key] = W2.reshape(a * D, b * D, kh, kw)
    return _band_cache[key]


def _conv3d_2d(x: torch.Tensor, conv: torch.nn.Conv3d) -> torch.Tensor:
    B, C, D, H, W = x.shape
    y = torch.nn.functional.conv2d(x.reshape(B, C * D, H, W), _banded(conv.weight, D, False), None,
                                   stride=conv.stride[1:], padding=conv.padding[1:])
    return y.reshape(B, -1, D, *y.shape[-2:])


def _deconv3d_2d(x: torch.Tensor, conv: torch.nn.ConvTranspose3d) -> torch.Tensor:
    B, C, D, H, W = x.shape
    y = torch.nn.functional.conv_transpose2d(x.reshape(B, C * D, H, W), _banded(conv.weight, D, True),
                                             stride=conv.stride[1:], padding=conv.padding[1:],
                                             output_padding=conv.output_padding[1:])
    return y.reshape(B, -1, D, *y.shape[-2:])


def _bn_relu(x: torch.Tensor, bn: torch.nn.BatchNorm3d) -> torch.Tensor:
    return torch.relu(torch.nn.functional.batch_norm(x, bn.running_mean, bn.running_var, bn.weight, bn.bias,
                                                     False, 0.0, bn.eps))


def _fast_forward_3d(net: CostRegNet3D, x: torch.Tensor) -> torch.Tensor:
    def block(layer, y):
        return _bn_relu(_conv3d_2d(y, layer.conv), layer.bn)

    def up(seq, y):
        return _bn_relu(_deconv3d_2d(y, seq[0]), seq[1])

    c2 = block(net.conv2, block(net.conv1, x))
    c4 = block(net.conv4, block(net.conv3, c2))
    y = block(net.conv6, block(net.conv5, c4))
    y = c4 + up(net.conv7, y)
    y = c2 + up(net.conv9, y)
    y = x + up(net.conv11, y)
    return net.prob(y)

