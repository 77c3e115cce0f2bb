"""Bicubic resampling written so that an ONNX graph holds it with PyTorch's numbers.

``F.interpolate(mode="bicubic")`` with a size computed from the input's (symbolic) size stops
``torch.onnx.export`` (DINOv2's position-embedding resize), and ONNX's ``Resize`` in cubic mode is
implemented in different ways by different runtimes. :func:`bicubic_resize` uses only gathers and
element-wise arithmetic, which every ONNX runtime (onnxruntime, TensorRT, OpenCV DNN) runs alike: Keys'
cubic with a = -0.75, source index ``scale * (i + 0.5) - 0.5``, border pixels repeated, one axis after the
other, as PyTorch's CPU kernel; the scale is ``in / out`` (``size=``) or ``1 / factor`` (``scale_factor=``,
DINOv2's form) as PyTorch computes them. The results agree with PyTorch's to float rounding (about 1e-6
relative: the kernel's polynomial and sums round differently), not to the bit.
"""

from __future__ import annotations

import torch

CUBIC_A = -0.75
"""Keys' cubic convolution parameter of PyTorch's (and OpenCV's) bicubic interpolation."""


def _cubic_coefficients(t: torch.Tensor) -> list[torch.Tensor]:
    """The four tap weights of source offsets -1, 0, 1, 2 at fraction ``t`` in [0, 1) (PyTorch's
    ``get_cubic_upsample_coefficients``)."""
    a = CUBIC_A

    def near(x):  # |x| <= 1
        return ((a + 2) * x - (a + 3)) * x * x + 1

    def far(x):  # 1 < |x| < 2
        return ((a * x - 5 * a) * x + 8 * a) * x - 4 * a

    u = 1.0 - t
    return [far(t + 1.0), near(t), near(u), far(u + 1.0)]


def _cubic_axis(x: torch.Tensor, axis: int, out_size, scale: torch.Tensor) -> torch.Tensor:
    """Bicubic resampling of ``x`` along ``axis`` to ``out_size`` samples, source index
    ``scale * (i + 0.5) - 0.5`` (``scale`` a float32 scalar tensor), border samples repeated."""
    n = x.shape[axis]
    i = torch.arange(out_size, device=x.device, dtype=torch.float32)
    src = scale * (i + 0.5) - 0.5
    base = torch.floor(src)
    taps = _cubic_coefficients(src - base)
    base = base.to(torch.int64)
    shape = [1] * x.dim()
    shape[axis] = -1
    out = None
    for k, w in enumerate(taps):
        idx = (base + (k - 1)).clamp(0, n - 1)
        term = torch.index_select(x, axis, idx) * w.reshape(shape)
        out = term if out is None else out + term
    return out


def bicubic_resize(x: torch.Tensor, size, scale: tuple | None = None) -> torch.Tensor:
    """``F.interpolate(x, size, mode="bicubic", align_corners=False)`` for [N, C, H, W] ``x`` in gathers and
    element-wise arithmetic (see the module docstring); ``size`` may be symbolic.

    ``scale``: (sy, sx) source pixels per output pixel as float32 scalar tensors; default ``in / out`` in
    float32, PyTorch's scale for ``size=``; :func:`inverse_factor` gives the one of ``scale_factor=``.
    """
    H, W = x.shape[-2:]
    out_h, out_w = size
    if scale is None:
        scale = (_scalar(H, torch.float32) / _scalar(out_h, torch.float32),
                 _scalar(W, torch.float32) / _scalar(out_w, torch.float32))
    y = _cubic_axis(x, x.dim() - 1, out_w, scale[1])
    return _cubic_axis(y, x.dim() - 2, out_h, scale[0])


def inverse_factor(factor) -> torch.Tensor:
    """PyTorch's scale for ``scale_factor=factor``: 1 / factor in float64, rounded to float32 (``factor``: a
    number or a float64 scalar tensor)."""
    return (1.0 / _scalar(factor, torch.float64)).to(torch.float32)


def _scalar(v, dtype: torch.dtype) -> torch.Tensor:
    """A scalar tensor of ``v`` (a number, a symbolic size or a tensor)."""
    if isinstance(v, torch.Tensor):
        return v.to(dtype)
    return torch.scalar_tensor(v, dtype=dtype)
