"""3-D U-Nets regularising the cost volumes of stages 2-4."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models import prepared
from mvsformerpp.models.layers import ConvBnReLU3d, DeconvBnReLU3d
from mvsformerpp.models.prepared import fused_conv_bn


def _unet_forward(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """The U-Net both regularisers share: three strided levels, additive skips, a logit head."""
    c2 = net.conv2(net.conv1(x))
    c4 = net.conv4(net.conv3(c2))
    y = net.conv6(net.conv5(c4))
    y = c4 + net.conv7(y)
    y = c2 + net.conv9(y)
    y = x + net.conv11(y)
    return net.prob(y)


class _UNet3d(nn.Module):
    """A cost-volume U-Net (levels ``conv1`` .. ``conv11``, ``prob``) run by :func:`_unet_forward`."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        forms = prepared.forms(self)
        if forms is not None and x.device.type == "cpu":
            return _unet_banded(self, forms, x)  # the same function, faster on CPU (see below)
        return _unet_forward(self, x)

    def build_inference_forms(self) -> dict:
        return _unet_forms(self)


class CostRegNet(_UNet3d):
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


def _deconv_hw(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.ConvTranspose3d(cin, cout, 3, stride=(1, 2, 2), padding=1, output_padding=(0, 1, 1), bias=False),
        nn.BatchNorm3d(cout),
        nn.ReLU(inplace=True),
    )


class CostRegNet3D(_UNet3d):
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


# ------------------------------------------------------------------------------------------------
# Prepared inference on the CPU (see mvsformerpp.models.prepared): the same function as the modules
# above, up to float rounding. A 3-D convolution over a volume [B, C, D, H, W] equals a 2-D convolution over the
# channels (c, d) of its [B, C*D, H, W] view with a depth-banded weight,
# W2[(o, d'), (c, d)] = W[o, c, d - s d' + p] (depth stride s, padding p; transposed alike), and
# oneDNN runs these wide 2-D convolutions, in channels-last memory, several times faster than the
# thin 3-D ones (the stage-2 logit head, with one output channel, otherwise takes PyTorch's slow
# im2col path). Eval BatchNorm is folded into each convolution, and ReLU and the skip additions run in
# place, so every level allocates one map.

_LEVELS = ("conv1", "conv2", "conv3", "conv4", "conv5", "conv6", "conv7", "conv9", "conv11", "prob")


def _unet_forms(net: nn.Module) -> dict:
    """Prepared forms of a U-Net (:mod:`.inference`): each level's convolution with its eval BatchNorm
    folded in; the depth-banded weights are made from them per input depth on first use."""
    forms = {"banded": {}}
    for name in _LEVELS:
        layer = getattr(net, name)  # ConvBnReLU3d / DeconvBnReLU3d, (ConvTranspose3d, BatchNorm3d, ReLU), Conv3d
        if isinstance(layer, nn.Sequential):
            conv, bn = layer[0], layer[1]
        else:
            conv, bn = (layer.conv, layer.bn) if hasattr(layer, "conv") else (layer, None)
        forms[name] = (conv, *fused_conv_bn(conv, bn))
    return forms


def _band(weight: torch.Tensor, D: int, transposed: bool, stride: int, pad: int, out_pad: int):
    """(depth-banded 2-D weight, output depth) of a (transposed) 3-D conv weight for input depth D.

    Both relate a strided depth i to a dense depth j = s i + k - p through tap k: a convolution's
    output depth to its input depth, a transposed convolution's input depth to its output depth;
    the weight layouts ([out, in, ...] and [in, out, ...]) put the strided side first in both.
    """
    a, b, K, kh, kw = weight.shape
    if transposed:
        n_strided, n_dense = D, (D - 1) * stride - 2 * pad + K + out_pad
    else:
        n_strided, n_dense = (D + 2 * pad - K) // stride + 1, D
    W2 = weight.new_zeros(a, n_strided, b, n_dense, kh, kw)
    for i in range(n_strided):
        for k in range(K):
            if 0 <= stride * i + k - pad < n_dense:
                W2[:, i, :, stride * i + k - pad] = weight[:, :, k]
    return W2.reshape(a * n_strided, b * n_dense, kh, kw), (n_dense if transposed else n_strided)


def _banded(forms: dict, name: str, D: int):
    """(banded weight, bias) of level ``name`` for input depth D, made once per D."""
    key = (name, D)
    if key not in forms["banded"]:
        conv, w, bias = forms[name]
        transposed = isinstance(conv, nn.ConvTranspose3d)
        out_pad = conv.output_padding[0] if transposed else 0
        w, D_out = _band(w, D, transposed, conv.stride[0], conv.padding[0], out_pad)
        bias = None if bias is None else bias.repeat_interleave(D_out)
        forms["banded"][key] = (w.contiguous(memory_format=torch.channels_last), bias)
    return forms["banded"][key]


def _banded_conv2d(forms: dict, name: str, x2: torch.Tensor) -> torch.Tensor:
    """Level ``name`` (3-D convolution then eval BatchNorm) on a volume viewed as [B, C*D, H, W]
    -> [B, C'*D', H', W']."""
    conv = forms[name][0]
    w, b = _banded(forms, name, x2.shape[1] // conv.in_channels)
    if isinstance(conv, nn.ConvTranspose3d):
        return F.conv_transpose2d(x2, w, b, stride=conv.stride[1:], padding=conv.padding[1:],
                                  output_padding=conv.output_padding[1:])
    return F.conv2d(x2, w, b, stride=conv.stride[1:], padding=conv.padding[1:])


def _unet_banded(net: nn.Module, forms: dict, x: torch.Tensor) -> torch.Tensor:
    """_unet_forward on [B, C*D, H, W] maps, channels-last after the first level (no layout
    conversions of full-resolution outputs), with in-place ReLU and skips; logits [B, 1, D, H, W]."""
    B, C, D, H, W = x.shape
    x2 = x.reshape(B, C * D, H, W)

    def level(name, y):
        return _banded_conv2d(forms, name, y).relu_().contiguous(memory_format=torch.channels_last)

    c2 = level("conv2", level("conv1", x2))
    c4 = level("conv4", level("conv3", c2))
    y = level("conv6", level("conv5", c4))
    y = level("conv7", y).add_(c4)
    del c4
    y = level("conv9", y).add_(c2)
    del c2
    y = level("conv11", y).add_(x2)
    return _banded_conv2d(forms, "prob", y).contiguous().unsqueeze(1)  # one logit channel per depth
