"""SVA part 2 on the 1/8 features (the reference's ``FMT_with_pathway``): a normalised 2-D sine
positional encoding, linear-attention self/cross layers (source views attend to the reference) and a
top-down pathway that carries the result to the 1/4, 1/2 and 1/1 features.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models import prepared
from mvsformerpp.models.features import per_image
from mvsformerpp.models.sva import LinearAttentionBlock


def sine_position_encoding_2d(channels: int, h: int, w: int, max_shape=(128, 128)) -> torch.Tensor:
    """Normalised 2-D sine PE [1, C, h, w]: positions (i+1)*128/h, (j+1)*128/w span (0, 128] at any size.

    Channel 4k = sin(x w_k), 4k+1 = cos(x w_k), 4k+2 = sin(y w_k), 4k+3 = cos(y w_k),
    w_k = 10000^(-2k/(C/2)).
    """
    y = torch.ones(h, w).cumsum(0)[None] * max_shape[0] / h
    x = torch.ones(h, w).cumsum(1)[None] * max_shape[1] / w
    div = torch.exp(torch.arange(0, channels // 2, 2).float() * (-math.log(10000.0) / (channels // 2)))[:, None, None]
    pe = torch.zeros(channels, h, w)
    pe[0::4] = torch.sin(x * div)
    pe[1::4] = torch.cos(x * div)
    pe[2::4] = torch.sin(y * div)
    pe[3::4] = torch.cos(y * div)
    return pe[None]


class FeatureMatchingTransformer(nn.Module):
    """Layers named ``self``/``cross``; the reference view runs the self layers, source views all layers."""

    def __init__(self, dim: int = 64, num_heads: int = 4, layer_names=("self", "cross", "self", "cross"),
                 mlp_ratio: float = 4.0):
        super().__init__()
        self.dim, self.layer_names = dim, tuple(layer_names)
        self.layers = nn.ModuleList(
            [LinearAttentionBlock(dim, num_heads, mlp_ratio, norm_kv=True) for _ in self.layer_names]
        )
        self._pe: dict[tuple, torch.Tensor] = {}  # cache, not part of the state_dict

    def position_encoding(self, x: torch.Tensor) -> torch.Tensor:
        if torch.compiler.is_exporting():  # a portable graph's sizes are symbolic: computed there, not cached
            return sine_position_encoding_2d(self.dim, x.shape[-2], x.shape[-1]).to(x.device, x.dtype)
        key = (x.shape[-2], x.shape[-1], x.device, x.dtype)
        if key not in self._pe:
            self._pe[key] = sine_position_encoding_2d(self.dim, x.shape[-2], x.shape[-1]).to(x.device, x.dtype)
        return self._pe[key]

    def forward(self, ref: torch.Tensor, src: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """ref [B, C, h, w]; src [B*S, C, h, w] with S source views per sample (or None).

        Returns the refined reference and source features in the same shapes.
        """
        B, C, h, w = ref.shape
        pe = self.position_encoding(ref)
        r = (ref + pe).flatten(2).transpose(1, 2)
        ref_list = []
        for layer, name in zip(self.layers, self.layer_names):
            if name == "self":
                r = layer(r)
                ref_list.append(r)
        ref_out = r.transpose(1, 2).reshape(B, C, h, w)
        if src is None:
            return ref_out, None
        S = src.shape[0] // B
        s = (src + pe).flatten(2).transpose(1, 2)
        for i, (layer, name) in enumerate(zip(self.layers, self.layer_names)):
            if name == "self":
                s = layer(s)
            else:
                kv = ref_list[i if len(ref_list) == len(self.layers) else i // 2]
                s = layer(s, kv)  # the S source views of a sample share its reference keys/values
        return ref_out, s.transpose(1, 2).reshape(B * S, C, h, w)


class FMTWithPathway(nn.Module):
    """FMT on stage-1 features, then F_{s+1}' = Conv3x3(up(Conv1x1(F_s')) + F_{s+1}) for the finer stages."""

    def __init__(self, dim: int = 64, num_heads: int = 4, layer_names=("self", "cross", "self", "cross"),
                 base_channel: int = 8):
        super().__init__()
        self.FMT = FeatureMatchingTransformer(dim, num_heads, layer_names)
        b = base_channel
        self.dim_reduction_1 = nn.Conv2d(b * 8, b * 4, 1, bias=False)
        self.dim_reduction_2 = nn.Conv2d(b * 4, b * 2, 1, bias=False)
        self.dim_reduction_3 = nn.Conv2d(b * 2, b, 1, bias=False)
        self.smooth_1 = nn.Conv2d(b * 4, b * 4, 3, padding=1, bias=False)
        self.smooth_2 = nn.Conv2d(b * 2, b * 2, 3, padding=1, bias=False)
        self.smooth_3 = nn.Conv2d(b, b, 3, padding=1, bias=False)

    @staticmethod
    def _upsample_add(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        # align_corners=False here, unlike the FPN decoder (as the official code does).
        if not prepared.lean():
            return F.interpolate(x.float(), size=y.shape[-2:], mode="bilinear") + y
        # without autograd: channels-last (the smoothing convolutions run faster) and an in-place sum
        x = x.float().contiguous(memory_format=torch.channels_last)
        return F.interpolate(x, size=y.shape[-2:], mode="bilinear").add_(y)

    def pathway(self, s1, *finer):
        """Carry refined stage-1 features down to the finer stages (as many as given, coarsest first)."""
        out, s = [], s1
        steps = ((self.dim_reduction_1, self.smooth_1), (self.dim_reduction_2, self.smooth_2),
                 (self.dim_reduction_3, self.smooth_3))
        for (reduce, smooth), f in zip(steps, finer):
            s = smooth(self._upsample_add(reduce(s), f))
            out.append(s)
        return out

    def forward(self, features: list[torch.Tensor]) -> list[torch.Tensor]:
        """features: 4 tensors [B, V, C_s, H_s, W_s] (or the first 1-3 of them) -> the same shapes, refined.

        In eval without autograd the finer features are refined in place (their tensors are overwritten).
        """
        f1, finer = features[0], [f.flatten(0, 1) for f in features[1:]]
        B, V = f1.shape[:2]
        ref, src = self.FMT(f1[:, 0], f1[:, 1:].flatten(0, 1) if V > 1 else None)
        s1 = ref[:, None] if src is None else torch.cat([ref[:, None], src.reshape(B, V - 1, *src.shape[1:])], 1)
        s1 = s1.flatten(0, 1)
        if not finer:
            refined = []
        elif not prepared.lean():
            refined = self.pathway(s1, *finer)
        else:  # image by image, each result written over its input: a much smaller working set

            refined = per_image(self.pathway, len(s1), s1, *finer, out=finer)
        return [s.reshape(B, V, *s.shape[1:]) for s in (s1, *refined)]
