"""DINOv2 ViT backbone (Oquab et al. 2023), built so that Meta's ``dinov2_vitb14_pretrain.pth`` loads
1:1 under the ``vit.`` prefix, as in the official code: 1 cls token, no register tokens, LayerScale
per block, LN eps 1e-6, a 37x37 learned positional embedding interpolated to the input's token grid.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models.attention import softmax_attention
from mvsformerpp.models.layers import LayerScale, Mlp


class PatchEmbed(nn.Module):
    def __init__(self, patch_size: int, embed_dim: int):
        super().__init__()
        self.proj = nn.Conv2d(3, embed_dim, kernel_size=patch_size, stride=patch_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)  # [N, h*w, C]


class SelfAttention(nn.Module):
    def __init__(self, dim: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.qkv = nn.Linear(dim, dim * 3, bias=True)
        self.proj = nn.Linear(dim, dim)
        self.backend = "sdpa"

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, N, C = x.shape
        qkv = self.qkv(x).reshape(B, N, 3, self.num_heads, C // self.num_heads).permute(2, 0, 3, 1, 4)
        out = softmax_attention(qkv[0], qkv[1], qkv[2], backend=self.backend)
        return self.proj(out.transpose(1, 2).reshape(B, N, C))


class Block(nn.Module):
    """Pre-LN transformer block with LayerScale."""

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = SelfAttention(dim, num_heads)
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.ls1.residual(x, self.attn(self.norm1(x)))
        return self.ls2.residual(x, self.mlp(self.norm2(x)))


class DinoVisionTransformer(nn.Module):
    """ViT with DINOv2's parameter names; ``forward_taps`` returns the three SVA inputs."""

    def __init__(
        self,
        embed_dim: int = 768,
        depth: int = 12,
        num_heads: int = 12,
        mlp_ratio: float = 4.0,
        patch_size: int = 14,
        img_size: int = 518,
        num_taps: int = 3,
    ):
        super().__init__()
        self.embed_dim, self.patch_size, self.num_taps = embed_dim, patch_size, num_taps
        grid = img_size // patch_size
        self.patch_embed = PatchEmbed(patch_size, embed_dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, grid * grid + 1, embed_dim))
        self.mask_token = nn.Parameter(torch.zeros(1, embed_dim))  # in Meta's weights; unused here
        self.blocks = nn.ModuleList([Block(embed_dim, num_heads, mlp_ratio) for _ in range(depth)])
        self.norm = nn.LayerNorm(embed_dim, eps=1e-6)
        nn.init.trunc_normal_(self.pos_embed, std=0.02)
        nn.init.normal_(self.cls_token, std=1e-6)

    def interpolate_pos_embed(self, h: int, w: int) -> torch.Tensor:
        """Positional embedding for an h x w token grid.

        Bicubic resampling of the square grid with DINOv2's ``scale_factor=(h + 0.1)/grid`` form (not
        ``size=``): the two differ in the last bits, and the reference uses this one.
        """
        n = self.pos_embed.shape[1] - 1
        grid = int(math.sqrt(n))
        if h * w == n and h == w:
            return self.pos_embed
        pos = self.pos_embed.float()
        patch = pos[:, 1:].reshape(1, grid, grid, -1).permute(0, 3, 1, 2)
        patch = F.interpolate(patch, scale_factor=((h + 0.1) / grid, (w + 0.1) / grid), mode="bicubic")
        if patch.shape[-2:] != (h, w):
            raise RuntimeError(f"positional embedding resampled to {tuple(patch.shape[-2:])}, expected {(h, w)}")
        patch = patch.permute(0, 2, 3, 1).reshape(1, h * w, -1)
        return torch.cat((pos[:, :1], patch), dim=1).to(self.pos_embed.dtype)

    def tap_blocks(self) -> list[int]:
        """Block indices whose outputs feed SVA: every depth/num_taps blocks, the last one normed."""
        interval = len(self.blocks) // self.num_taps
        return [i for i in range(len(self.blocks)) if (i + 1) % interval == 0 and i != len(self.blocks) - 1][
            : self.num_taps - 1
        ] + [len(self.blocks) - 1]

    def forward_taps(self, x: torch.Tensor, pos_embed: torch.Tensor | None = None) -> list[torch.Tensor]:
        """[N, 3, H, W] (H, W multiples of the patch size) -> taps, each [N, h*w, C] (cls dropped).

        ``pos_embed``: the positional embedding of this token grid, [1, 1 + h*w, C] (default
        :meth:`interpolate_pos_embed`; a portable graph gives its own form of it)."""
        _, _, H, W = x.shape
        h, w = H // self.patch_size, W // self.patch_size
        tokens = self.patch_embed(x)
        tokens = torch.cat((self.cls_token.expand(tokens.shape[0], -1, -1), tokens), dim=1)
        tokens = tokens + (self.interpolate_pos_embed(h, w) if pos_embed is None else pos_embed)
        taps = set(self.tap_blocks()[:-1])
        out = []
        for i, blk in enumerate(self.blocks):
            tokens = blk(tokens)
            if i in taps:
                out.append(tokens[:, 1:])
        out.append(self.norm(tokens)[:, 1:])
        return out
