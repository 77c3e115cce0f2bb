"""3-D U-Nets regularising the cost volumes of stages 2-4."""

from __future__ import annotations

import functools

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
        if forms is not None and x.device.type == "cpu":  # the same function, faster on CPU (see below)
            if forms["depth_batched"] and not torch.is_autocast_enabled("cpu"):
                return _unet_depth_batched(self, forms, x)
            return _unet_banded(self, forms, x)
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
# place, so every level allocates one map. This depth-banded form runs under bf16 autocast and where the
# depth-batched form (further below), the faster one, cannot.

_LEVELS = ("conv1", "conv2", "conv3", "conv4", "conv5", "conv6", "conv7", "conv9", "conv11", "prob")


def _unet_forms(net: nn.Module) -> dict:
    """Prepared forms of a U-Net (:mod:`.prepared`): each level's convolution with its eval BatchNorm
    folded in, and which form runs; the depth-banded (per input depth) and per-tap weights are made from
    them on first use."""
    forms = {"banded": {}, "stacked": {}, "taps": {}}
    for name in _LEVELS:
        layer = getattr(net, name)  # ConvBnReLU3d / DeconvBnReLU3d, (ConvTranspose3d, BatchNorm3d, ReLU), Conv3d
        if isinstance(layer, nn.Sequential):
            conv, bn = layer[0], layer[1]
        else:
            conv, bn = (layer.conv, layer.bn) if hasattr(layer, "conv") else (layer, None)
        forms[name] = (conv, *fused_conv_bn(conv, bn))
    forms["depth_batched"] = _depth_batched_possible(forms)
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


# The depth-batched form (the default where this PyTorch build offers oneDNN's accumulating convolution,
# below; fp32): the banded weights above are mostly zeros when the volume has many depths (a kernel of 3
# taps touches 3 of D input depths: 22 of the 64 blocks at D = 8), and oneDNN multiplies them all.
# Instead each level runs 2-D convolutions with the depths as the batch ([B*D, C, H, W], channels-last),
# one per depth tap k of the kernel: out[d'] = sum over k of W_k * x[s d' + k - p]. A convolution level
# convolves the tap that reaches every output depth first (with the bias), then adds each other tap's
# convolution of its run of input depths into its run of output depths inside the convolution (oneDNN's
# sum post-op). A transposed level (out[s d + k - p] += T_k x[d]) has no such entry point: it stacks its
# taps as the output channels of one transposed convolution ([C, K*C', kh, kw]) and sums them per output
# depth, one depth at a time, so that the sum, bias, ReLU and skip stay in the core's cache. The
# full-resolution tail (conv11, then the logits) stays banded: with 8 channels at full resolution the
# per-depth sums cost more than the zeros they save. The U-Nets alone against the banded form, 2 cores,
# fp32, at 640x480 photos: 1.2x (stage 2), 1.7x (stage 3), 1.07x (stage 4).


def _taps(forms: dict, name: str) -> list[torch.Tensor]:
    """A convolution level's fused weight split by depth tap: K weights [C', C, kh, kw]."""
    if name not in forms["taps"]:
        w = forms[name][1]
        forms["taps"][name] = [w[:, :, k].contiguous(memory_format=torch.channels_last) for k in range(w.shape[2])]
    return forms["taps"][name]


def _stacked(forms: dict, name: str) -> torch.Tensor:
    """A transposed level's fused weight [C, C', K, kh, kw] with its taps stacked: [C, K*C', kh, kw]."""
    if name not in forms["stacked"]:
        w = forms[name][1]
        forms["stacked"][name] = w.permute(0, 2, 1, 3, 4).reshape(w.shape[0], -1, *w.shape[3:]).contiguous(
            memory_format=torch.channels_last)
    return forms["stacked"][name]


@functools.lru_cache(maxsize=1)
def _accumulating():
    """oneDNN's convolution that adds its result into a given channels-last tensor in place
    (``other += conv2d(x, w)``), as this PyTorch build exposes it (an internal operator), or None where it
    does not, or where it disagrees with ``F.conv2d`` on a probe; checked once per process."""
    try:
        candidate = torch.ops.mkldnn._convolution_pointwise_.binary
        g = torch.Generator().manual_seed(0)
        x = torch.randn(2, 4, 5, 6, generator=g).contiguous(memory_format=torch.channels_last)
        w = torch.randn(3, 4, 3, 3, generator=g).contiguous(memory_format=torch.channels_last)
        other = torch.randn(2, 3, 3, 3, generator=g).contiguous(memory_format=torch.channels_last)
        expected = other + F.conv2d(x, w, stride=2, padding=1)
        with torch.no_grad():
            candidate(other, x, w, None, [1, 1], [2, 2], [1, 1], 1, "add", 1.0, None, [], None)
    except (AttributeError, RuntimeError):
        return None
    return candidate if torch.allclose(other, expected, atol=1e-5) else None


def _depth_batched_possible(forms: dict) -> bool:
    """Whether the depth-batched form can run a U-Net: the accumulating convolution exists, every
    convolution level has a depth tap that reaches every output depth (an odd kernel, padded by half),
    and every transposed level reaches every output depth with some tap (stride <= kernel, padding
    within the kernel, output padding <= padding)."""
    convs = [forms[name][0] for name in _LEVELS]
    plain = [c for c in convs if not isinstance(c, nn.ConvTranspose3d)]
    transposed = [c for c in convs if isinstance(c, nn.ConvTranspose3d)]
    return (_accumulating() is not None and all(c.padding[0] == c.kernel_size[0] // 2 for c in plain)
            and all(c.stride[0] <= c.kernel_size[0] and c.padding[0] < c.kernel_size[0]
                    and c.output_padding[0] <= c.padding[0] for c in transposed))


def _tap_runs(conv: nn.Module, D: int) -> tuple[int, list[tuple[int, int, int, int]]]:
    """(output depths, [(tap, first output, end output, first input)]) of a convolution over D depths:
    tap k adds W_k * x[s j + k - p] to out[j] for j in [first output, end output); the tap that reaches
    every output depth first."""
    K, s, p = conv.kernel_size[0], conv.stride[0], conv.padding[0]
    n_out = (D + 2 * p - K) // s + 1
    runs = []
    for k in range(K):
        js = [j for j in range(n_out) if 0 <= s * j + k - p < D]
        if js:
            runs.append((k, js[0], js[-1] + 1, s * js[0] + k - p))
    return n_out, sorted(runs, key=lambda r: r[2] - r[1] < n_out)


def _conv_level(forms: dict, name: str, y: torch.Tensor, B: int, relu: bool) -> torch.Tensor:
    """A convolution level on depth-batched maps [B*D, C, H, W] -> [B*D', C', H', W'], channels-last."""
    conv, _, bias = forms[name]
    w = _taps(forms, name)
    D = y.shape[0] // B
    n_out, runs = _tap_runs(conv, D)
    s, stride, pad = conv.stride[0], list(conv.stride[1:]), list(conv.padding[1:])
    y5 = y.unflatten(0, (B, D))
    (k, _, _, i0), accumulate = runs[0], _accumulating()
    first = y5[:, i0:i0 + s * n_out:s].flatten(0, 1).contiguous(memory_format=torch.channels_last)  # its inputs
    out = F.conv2d(first, w[k], bias, stride=stride, padding=pad).contiguous(memory_format=torch.channels_last)
    del first
    out5 = out.unflatten(0, (B, n_out))
    for k, j0, j1, i0 in runs[1:]:
        for b in range(B):  # out5[b, j0:j1] += W_k * x[b, i0::s] (one sample's run of depths is contiguous)
            part = y5[b, i0:i0 + s * (j1 - j0):s].contiguous(memory_format=torch.channels_last)
            accumulate(out5[b, j0:j1], part, w[k], None, pad, stride, [1, 1], 1, "add", 1.0, None, [], None)
    return out.relu_() if relu else out


TAPS_BYTES = 1 << 27
"""Working-set size of the stacked taps of a transposed level in the depth-batched form: larger volumes
run their input depths in chunks of about this many bytes of taps."""


def _transposed_level(forms: dict, name: str, y: torch.Tensor, B: int, skip: torch.Tensor) -> torch.Tensor:
    """A transposed level, its ReLU, then + ``skip``, on depth-batched maps, channels-last. The stacked
    taps of a chunk of input depths are summed into the output depths they reach; an output depth is
    finished (bias, ReLU, skip) once its last term is in."""
    conv, _, bias = forms[name]
    D = y.shape[0] // B
    K, s, p = conv.kernel_size[0], conv.stride[0], conv.padding[0]
    n_out = (D - 1) * s - 2 * p + K + conv.output_padding[0]
    terms = [[(d, k) for d in range(D) for k in range(K) if s * d + k - p == j] for j in range(n_out)]
    w = _stacked(forms, name)
    y5 = y.unflatten(0, (B, D))
    skip = skip.permute(0, 2, 3, 1).unflatten(0, (B, n_out))
    out, started = None, [False] * n_out
    per_depth = 4 * B * w.shape[1] * skip.shape[2] * skip.shape[3]  # bytes of one input depth's taps
    step = max(1, min(D, TAPS_BYTES // per_depth))
    for a in range(0, D, step):
        b = min(D, a + step)
        taps = F.conv_transpose2d(y5[:, a:b].flatten(0, 1).contiguous(memory_format=torch.channels_last), w,
                                  stride=conv.stride[1:], padding=conv.padding[1:],
                                  output_padding=conv.output_padding[1:])
        _, KC, h, w_ = taps.shape
        taps = taps.permute(0, 2, 3, 1).view(B, b - a, h, w_, K, KC // K)  # NHWC rows, the taps split
        if out is None:
            out = taps.new_empty(B, n_out, h, w_, KC // K)
        for j in range(n_out):
            mine = [taps[:, d - a, :, :, k] for d, k in terms[j] if a <= d < b]
            if not mine:
                continue
            o = out[:, j]
            if started[j]:
                o.add_(mine[0])
            elif len(mine) >= 2:
                torch.add(mine[0], mine.pop(1), out=o)
            else:
                o.copy_(mine[0])
            started[j] = True
            for term in mine[1:]:
                o.add_(term)
            if max(d for d, _ in terms[j]) < b:  # its last term is in: finish it
                if bias is not None:
                    o.add_(bias)
                o.relu_().add_(skip[:, j])
        del taps
    return out.view(B * n_out, *out.shape[2:]).permute(0, 3, 1, 2)


def _unet_depth_batched(net: nn.Module, forms: dict, x: torch.Tensor) -> torch.Tensor:
    """_unet_forward with the depths in the batch (see above); logits [B, 1, D, H, W]."""
    B, C, D, H, W = x.shape
    x2 = x.permute(0, 2, 3, 4, 1).contiguous().view(B * D, H, W, C).permute(0, 3, 1, 2)  # channels-last

    def down(name, y):
        return _conv_level(forms, name, y, B, relu=True)

    c2 = down("conv2", down("conv1", x2))
    c4 = down("conv4", down("conv3", c2))
    y = down("conv6", down("conv5", c4))
    del x2
    y = _transposed_level(forms, "conv7", y, B, c4)
    del c4
    y = _transposed_level(forms, "conv9", y, B, c2)
    del c2
    # the banded tail: [B*n, C, h, w] -> [B, C*n, h, w] (channel c*n + d), channels-last
    n, h, w = y.shape[0] // B, *y.shape[-2:]
    y = y.permute(0, 2, 3, 1).unflatten(0, (B, n)).permute(0, 2, 3, 4, 1).reshape(B, h, w, -1).permute(0, 3, 1, 2)
    y = _banded_conv2d(forms, "conv11", y).relu_().contiguous(memory_format=torch.channels_last)
    y.add_(x.reshape(B, C * D, H, W))
    return _banded_conv2d(forms, "prob", y).contiguous().unsqueeze(1)  # one logit channel per depth
