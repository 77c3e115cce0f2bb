"""3-D U-Nets regularising the cost volumes of stages 2-4 (spec 6.2, 6.3)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models.layers import ConvBnReLU3d, DeconvBnReLU3d, fold_batchnorm


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
        if _fast_path(self, x):
            return _fast_forward_2(self, x)  # the same function, faster on CPU (see below)
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
        if _fast_path(self, x):
            return _fast_forward_3d(self, x)  # the same function, faster on CPU (see below)
        return _unet_forward(self, x)


# ------------------------------------------------------------------------------------------------
# Inference fast paths (CPU, eval). The same functions as the modules above, up to float rounding:
# - eval BatchNorm is an affine map, folded into the preceding convolution's weight and bias, and
#   ReLU and the U-Net's skip additions run in place, so every level allocates one tensor, not three;
# - a 3-D convolution whose depth kernel is 3 (padding 1) equals a 2-D convolution over channels
#   (c, d) with a depth-banded weight: W2[(o, d'), (c, d)] = W[o, c, d - d' + 1] for |d - d'| <= 1.
#   oneDNN runs these wider 2-D convolutions several times faster than the thin 3-D ones (the stage-2
#   logit head, with a single output channel, otherwise takes PyTorch's slow im2col path);
# - the 1x1x1 logit head of stages 3-4 is a 1x1 2-D convolution over (c, d).

_fold_cache: dict = {}


def _fast_path(net: nn.Module, x: torch.Tensor) -> bool:
    return not net.training and not torch.is_grad_enabled() and x.device.type == "cpu"


def _cache_key(*tensors: torch.Tensor, extra=()) -> tuple:
    return tuple((t.data_ptr(), t._version, t.dtype, t.device) for t in tensors) + tuple(extra)


def _band(weight: torch.Tensor, D: int, transposed: bool) -> torch.Tensor:
    """Depth-banded 2-D weight of a depth-kernel-3, depth-stride-1, depth-padding-1 (transposed) conv."""
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
    return W2.reshape(a * D, b * D, kh, kw)


def _folded(conv: nn.Module, bn: nn.Module | None, D: int | None = None):
    """(weight, bias) of conv with the eval BatchNorm bn folded in; depth-banded when D is given."""
    tensors = [conv.weight] + ([] if bn is None else [bn.weight, bn.bias, bn.running_mean, bn.running_var])
    key = _cache_key(*tensors, extra=(D,))
    if key not in _fold_cache:
        if len(_fold_cache) > 128:
            _fold_cache.clear()
        transposed = isinstance(conv, nn.ConvTranspose3d)
        w, bias = (conv.weight.detach(), None) if bn is None else fold_batchnorm(conv.weight, bn, transposed)
        if D is not None:
            w = _band(w, D, transposed)
            bias = None if bias is None else bias.repeat_interleave(D)
        _fold_cache[key] = (w, bias)
    return _fold_cache[key]


def _banded_conv2d(x2: torch.Tensor, conv: nn.Module, bn: nn.Module | None, D: int) -> torch.Tensor:
    """conv (3-D, depth kernel 3, depth stride 1) then eval bn as one 2-D convolution over channels
    (c, d): x2 is the volume [B, C, D, H, W] viewed as [B, C*D, H, W]."""
    w, b = _folded(conv, bn, D)
    if isinstance(conv, nn.ConvTranspose3d):
        return F.conv_transpose2d(x2, w, b, stride=conv.stride[1:], padding=conv.padding[1:],
                                  output_padding=conv.output_padding[1:])
    return F.conv2d(x2, w, b, stride=conv.stride[1:], padding=conv.padding[1:])


def _banded_conv(x: torch.Tensor, conv: nn.Module, bn: nn.Module | None) -> torch.Tensor:
    """_banded_conv2d on a volume [B, C, D, H, W] -> [B, C', D, H', W']."""
    B, C, D, H, W = x.shape
    y = _banded_conv2d(x.reshape(B, C * D, H, W), conv, bn, D)
    return y.reshape(B, -1, D, *y.shape[-2:])


def _conv_bn_relu(x: torch.Tensor, conv: nn.Module, bn: nn.Module) -> torch.Tensor:
    """ReLU(bn(conv(x))) for any 3-D (transposed) conv, with bn folded in."""
    w, b = _folded(conv, bn)
    if isinstance(conv, nn.ConvTranspose3d):
        y = F.conv_transpose3d(x, w, b, conv.stride, conv.padding, conv.output_padding)
    else:
        y = F.conv3d(x, w, b, conv.stride, conv.padding)
    return y.relu_()


def _unet_fast(net: nn.Module, x: torch.Tensor, block, up) -> torch.Tensor:
    """_unet_forward with in-place skips; block/up run one conv-bn-relu level."""
    c2 = block(net.conv2, block(net.conv1, x))
    c4 = block(net.conv4, block(net.conv3, c2))
    y = block(net.conv6, block(net.conv5, c4))
    y = up(net.conv7, y).add_(c4)
    del c4
    y = up(net.conv9, y).add_(c2)
    del c2
    return up(net.conv11, y).add_(x)


def _fast_forward_2(net: CostRegNet, x: torch.Tensor) -> torch.Tensor:
    def block(layer, y):
        return _conv_bn_relu(y, layer.conv, layer.bn)

    y = _unet_fast(net, x, block, block)
    return _banded_conv(y, net.prob, None)


def _fast_forward_3d(net: CostRegNet3D, x: torch.Tensor) -> torch.Tensor:
    """Every level as a banded 2-D convolution on [B, C*D, h, w] maps, channels-last after the first
    (oneDNN's preferred layout: no layout conversions of the full-resolution outputs)."""
    B, C, D, H, W = x.shape

    def block(layer, y):  # (only the first level's output needs the layout conversion)
        return _banded_conv2d(y, layer.conv, layer.bn, D).relu_().contiguous(memory_format=torch.channels_last)

    def up(seq, y):
        return _banded_conv2d(y, seq[0], seq[1], D).relu_()

    y = _unet_fast(net, x.reshape(B, C * D, H, W), block, up)
    # the 1x1x1 logit head: logits[d] = sum_c w_c y[c, d] + b, a 1x1 convolution over (c, d)
    Cy = y.shape[1] // D
    head = net.prob.weight.new_zeros(D, Cy, D)
    head[torch.arange(D), :, torch.arange(D)] = net.prob.weight.reshape(1, Cy)
    logits = F.conv2d(y, head.reshape(D, Cy * D, 1, 1), net.prob.bias.expand(D))
    return logits.contiguous().unsqueeze(1)
