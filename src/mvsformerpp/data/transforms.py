"""Training transforms of the reference: multi-scale resize and crop, photometric augmentation.

* :class:`ResizeCrop`: each sample is resized by ``s = max(clip(H e / H0, lo, 1), clip(W e / W0, lo, 1))``
  with ``e ~ U(scale_range)`` (H x W the batch's size, H0 x W0 the reference size of the data set:
  1200 x 1600 for DTU, 1536 x 2048 for BlendedMVS), photos by area averaging, depth and mask by nearest
  sampling; then every view is cropped at random to H x W, independently, with intrinsics adjusted
  (``diag(s) K``, then the crop offset off the principal point). The reference view's crop is drawn
  again until its 1/8-resolution mask has a valid pixel (at most ``max_tries`` times; then the sample
  is reported as having no valid depth).
* :class:`PhotometricAugment`: brightness, contrast, saturation and hue jitter in random order, then
  gamma, with the same factors for all views of a sample (the reference uses torchvision's
  ``ColorJitter(0.2, 0.1, 0.1, 0.05)`` and ``gamma ~ U(0.9, 1.1)``; the hue shift here rotates the
  chroma plane of YIQ instead of the HSV hue, which is the same operation up to the colour model).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.errors import InputError
from mvsformerpp.geometry.camera import crop_intrinsics, scale_intrinsics


def _resize_image(image: np.ndarray, h: int, w: int) -> np.ndarray:
    if image.shape[:2] == (h, w):
        return image
    x = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float()
    mode = "area" if h <= image.shape[0] and w <= image.shape[1] else "bilinear"
    kw = {} if mode == "area" else {"align_corners": False}
    y = F.interpolate(x, size=(h, w), mode=mode, **kw)[0].permute(1, 2, 0)
    return y.round().clamp(0, 255).to(torch.uint8).numpy()


def _resize_nearest(a: np.ndarray, h: int, w: int) -> np.ndarray:
    """cv2.INTER_NEAREST: destination pixel i takes source pixel floor(i * src / dst)."""
    ys = np.minimum((np.arange(h) * (a.shape[0] / h)).astype(np.int64), a.shape[0] - 1)
    xs = np.minimum((np.arange(w) * (a.shape[1] / w)).astype(np.int64), a.shape[1] - 1)
    return a[ys[:, None], xs[None, :]]


@dataclass(frozen=True)
class ResizeCrop:
    """Random resize then random crop to the batch resolution (see the module docstring)."""

    base_size: tuple[int, int] | None = None
    """(H0, W0) the scale is computed against; None: each sample's own reference image size."""
    scale_range: tuple[float, float] = (1.0, 1.2)
    """Range of the random enlargement e."""
    min_scale: float = 0.45
    """Lower clip of the scale (DTU 0.45, BlendedMVS 0.375)."""
    max_tries: int = 100
    """Crops drawn for the reference view before the sample is declared without valid depth."""
    center: bool = False
    """Centre crops instead of random ones (validation)."""
    require_valid: bool = True
    """A reference crop must hold valid depth (else the sample is an error); False keeps the last crop drawn
    (teacher labels that cover part of a photo)."""

    def scale(self, h0: int, w0: int, height: int, width: int, rng: np.random.Generator) -> float:
        bh, bw = self.base_size or (h0, w0)
        e = rng.uniform(*self.scale_range)
        sy, sx = np.clip(height * e / bh, self.min_scale, 1.0), np.clip(width * e / bw, self.min_scale, 1.0)
        return float(max(sy, sx))

    def crop_origin(self, h1: int, w1: int, height: int, width: int, rng: np.random.Generator, depth, mask,
                    what: str) -> tuple[int, int]:
        """Top-left of the crop: centred, or random and (given a mask) redrawn until its 1/8 grid has valid depth."""
        if self.center:
            return (h1 - height) // 2, (w1 - width) // 2
        for _ in range(self.max_tries if mask is not None else 1):
            y0, x0 = int(rng.integers(0, h1 - height + 1)), int(rng.integers(0, w1 - width + 1))
            if mask is None:
                return y0, x0
            m = mask[y0:y0 + height, x0:x0 + width] & (depth[y0:y0 + height, x0:x0 + width] > 0)
            if m[::8, ::8].any():
                return y0, x0
        if not self.require_valid:
            return y0, x0
        raise InputError(f"{what}: no crop of the reference view has valid ground-truth depth "
                         f"(tried {self.max_tries}); check its depth map and mask")

    def __call__(self, views: list, height: int, width: int, rng: np.random.Generator, what: str = "sample") -> list:
        h0, w0 = views[0].image.shape[:2]
        s = self.scale(h0, w0, height, width, rng)
        out = []
        for i, v in enumerate(views):
            vh, vw = v.image.shape[:2]
            h1, w1 = max(height, math.ceil(vh * s - 1e-6)), max(width, math.ceil(vw * s - 1e-6))
            if vh < height or vw < width:
                raise InputError(f"{what}: a {vw}x{vh} view cannot be cropped to {width}x{height}; train at a "
                                 "smaller resolution")
            K = scale_intrinsics(v.K, w1 / vw, h1 / vh)
            image = _resize_image(v.image, h1, w1)
            depth = None if v.depth is None else _resize_nearest(v.depth, h1, w1)
            mask = None if v.mask is None else _resize_nearest(v.mask, h1, w1)
            y0, x0 = self.crop_origin(h1, w1, height, width, rng, depth if i == 0 else None,
                                      mask if i == 0 else None, what)
            win = (slice(y0, y0 + height), slice(x0, x0 + width))
            out.append(dataclasses.replace(v, image=image[win], K=crop_intrinsics(K, x0, y0),
                                           depth=None if depth is None else depth[win],
                                           mask=None if mask is None else mask[win]))
        return out


def _gray(x: torch.Tensor) -> torch.Tensor:
    return (0.299 * x[:, 0] + 0.587 * x[:, 1] + 0.114 * x[:, 2])[:, None]


_YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])


def _hue(x: torch.Tensor, turns: float) -> torch.Tensor:
    yiq = torch.einsum("ij,vjhw->vihw", _YIQ, x)
    c, s = math.cos(2 * math.pi * turns), math.sin(2 * math.pi * turns)
    i, q = yiq[:, 1] * c - yiq[:, 2] * s, yiq[:, 1] * s + yiq[:, 2] * c
    return torch.einsum("ij,vjhw->vihw", torch.linalg.inv(_YIQ), torch.stack([yiq[:, 0], i, q], 1))


@dataclass(frozen=True)
class PhotometricAugment:
    """Colour jitter in random order and gamma, shared by all views of a sample (module docstring)."""

    brightness: float = 0.2
    contrast: float = 0.1
    saturation: float = 0.1
    hue: float = 0.05
    gamma: tuple[float, float] = (0.9, 1.1)

    def __call__(self, imgs: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
        """``imgs`` [V, 3, H, W] in [0, 1] -> the same, augmented."""
        b = rng.uniform(1 - self.brightness, 1 + self.brightness)
        c = rng.uniform(1 - self.contrast, 1 + self.contrast)
        s = rng.uniform(1 - self.saturation, 1 + self.saturation)
        h = rng.uniform(-self.hue, self.hue)
        g = rng.uniform(*self.gamma)
        ops = {
            0: lambda x: (x * b).clamp(0, 1),
            1: lambda x: (c * x + (1 - c) * _gray(x).mean(dim=(-1, -2), keepdim=True)).clamp(0, 1),
            2: lambda x: (s * x + (1 - s) * _gray(x)).clamp(0, 1),
            3: lambda x: _hue(x, h).clamp(0, 1),
        }
        for k in rng.permutation(4):
            imgs = ops[int(k)](imgs)
        return imgs.clamp(0, 1).pow(g)
