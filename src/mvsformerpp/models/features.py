"""Image features: the per-image part (DINOv2 taps, FPN encoder) and the multi-view decoding (SVA, FPN
decoder; the network then runs the FMT). Splitting them lets inference compute each image's features
once and reuse them for every reference view that uses the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from mvsformerpp.models import prepared
from mvsformerpp.models.dinov2 import DinoVisionTransformer
from mvsformerpp.models.fpn import FPNDecoder, FPNEncoder
from mvsformerpp.models.sva import SideViewAttention


@dataclass
class ImageFeatures:
    """Per-image work for N images (rows in batch-major order when used for a [B, V] batch).

    vit_taps: 3 tensors [N, h*w, C_vit]; vit_hw: the DINOv2 token grid (h, w);
    fpn: encoder outputs (conv01 [N,8,H,W], conv11 [N,16,H/2,W/2], conv21 [N,32,H/4,W/4], conv31 [N,64,H/8,W/8]).
    A dataclass of tensors: the feature cache concatenates and sizes it generically (``tree_cat``,
    ``tree_nbytes``).
    """

    vit_taps: list[torch.Tensor]
    vit_hw: tuple[int, int]
    fpn: tuple[torch.Tensor, ...]

    def __len__(self) -> int:
        return self.fpn[0].shape[0]

    def release(self) -> None:
        """Drop the references to the tensors (the object is empty afterwards)."""
        self.vit_taps, self.fpn = [], ()


def per_image(fn, count: int, *inputs: torch.Tensor, out: list[torch.Tensor] | None = None) -> list[torch.Tensor]:
    """fn over images one at a time (inputs sliced along dim 0), outputs written into preallocated
    tensors: the same result as fn on the whole batch (in eval), with a per-image working set and
    no concatenation copies. ``out`` may be inputs themselves (image i is read before it is written)."""
    outs = out
    for i in range(count):
        res = fn(*(x[i:i + 1] for x in inputs))
        if outs is None:
            outs = [torch.empty((count, *r.shape[1:]), dtype=r.dtype, device=r.device,
                                memory_format=_memory_format(r)) for r in res]
        for o, r in zip(outs, res):
            o[i:i + 1] = r
    return outs


def _memory_format(t: torch.Tensor) -> torch.memory_format:
    if t.dim() == 4 and not t.is_contiguous() and t.is_contiguous(memory_format=torch.channels_last):
        return torch.channels_last
    return torch.contiguous_format


def vit_input_size(H: int, W: int, rescale: float = 0.4375, patch: int = 14) -> tuple[int, int]:
    """DINOv2 input size: H*rescale and W*rescale floored to the patch size (the reference's rule)."""
    return int(H * rescale // patch * patch), int(W * rescale // patch * patch)


def encode_images(vit: DinoVisionTransformer, encoder: FPNEncoder, imgs: torch.Tensor,
                  vit_rescale: float = 0.4375) -> ImageFeatures:
    """[N, 3, H, W] ImageNet-normalised images -> :class:`ImageFeatures`.

    DINOv2 runs without autograd when it is frozen (all its parameters have requires_grad False).
    """
    N, _, H, W = imgs.shape
    vh, vw = vit_input_size(H, W, vit_rescale, vit.patch_size)
    if vh == 0 or vw == 0:
        raise ValueError(f"images of {H}x{W} are too small for the DINOv2 branch (need at least 32x32)")
    vit_imgs = F.interpolate(imgs, (vh, vw), mode="bicubic", align_corners=False)
    frozen = not any(p.requires_grad for p in vit.parameters())
    with torch.set_grad_enabled(torch.is_grad_enabled() and not frozen):
        taps = vit.forward_taps(vit_imgs)
    if not prepared.lean():
        fpn = tuple(encoder(imgs))
    else:  # eval without autograd: image by image, the same result with a smaller peak memory
        fpn = tuple(per_image(encoder, N, imgs))
    return ImageFeatures(taps, (vh // vit.patch_size, vw // vit.patch_size), fpn)


def decode_views(decoder_vit: SideViewAttention, decoder: FPNDecoder, feats: ImageFeatures, B: int,
                 V: int, levels: int = 4) -> list[torch.Tensor]:
    """SVA on the DINOv2 tokens of each sample's views, added to conv31, then the FPN decoder:
    ``levels`` tensors [B, V, C_s, H_s, W_s] for stages 1..levels (1/8 ... 1/1). ``feats`` holds B*V images in
    batch-major order (view 0 of each sample is its reference). Every sample uses its own DINOv2
    features (the reference gives all samples sample 0's in eval mode)."""
    taps = [t.reshape(B, V, *t.shape[1:]) for t in feats.vit_taps]
    vit_feat = decoder_vit(taps, feats.vit_hw)  # [B*V, 64, 4h, 4w]
    conv01, conv11, conv21, conv31 = feats.fpn
    if vit_feat.shape[-2:] != conv31.shape[-2:]:
        vit_feat = F.interpolate(vit_feat, size=conv31.shape[-2:], mode="bilinear", align_corners=False)
    conv31 = conv31 + vit_feat
    if not prepared.lean():  # in training, BatchNorm batch statistics over all B*V images
        stages = decoder(conv01, conv11, conv21, conv31, levels)
    else:  # eval without autograd: image by image, the same result with a much smaller working set
        stages = per_image(lambda *maps: decoder(*maps, levels), B * V, conv01, conv11, conv21, conv31)
    return [s.reshape(B, V, *s.shape[1:]) for s in stages]

