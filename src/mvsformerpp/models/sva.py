"""Side View Attention (paper sec. 3.2): linear-attention transformer blocks that let each
source view attend to the reference view, on the DINOv2 tokens, then a projection/upsampler to 1/8.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models import prepared
from mvsformerpp.models.attention import linear_attention
from mvsformerpp.models.layers import LayerScale, Mlp
from mvsformerpp.models.prepared import fused_conv_bn


class LinearAttention(nn.Module):
    """Multi-head linear attention with separate q/k/v projections (no bias) and an output projection."""

    def __init__(self, dim: int, num_heads: int):
        super().__init__()
        self.num_heads = num_heads
        self.q_proj = nn.Linear(dim, dim, bias=False)
        self.k_proj = nn.Linear(dim, dim, bias=False)
        self.v_proj = nn.Linear(dim, dim, bias=False)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, key: torch.Tensor | None = None, value: torch.Tensor | None = None):
        """x [B*S, N, C]; key, value [B, M, C] (default x), shared by S consecutive query samples."""
        B, N, C = x.shape
        key = x if key is None else key
        value = x if value is None else value

        def heads(t):
            return t.reshape(t.shape[0], -1, self.num_heads, C // self.num_heads)

        out = linear_attention(heads(self.q_proj(x)), heads(self.k_proj(key)), heads(self.v_proj(value)))
        return self.proj(out.reshape(B, N, C).to(x.dtype))


class LinearAttentionBlock(nn.Module):
    """Pre-LN block: x += ls1 * Attn(LN1(x), k, v); x += ls2 * MLP(LN2(x)).

    ``norm_kv``: keys/values of cross-attention also go through LN1 (FMT) or enter raw (SVA on
    DINOv2 tokens, the reference's ``pre_norm_query``), as the official code does.
    """

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float = 4.0, norm_kv: bool = False):
        super().__init__()
        self.norm_kv = norm_kv
        self.norm1 = nn.LayerNorm(dim)
        self.attn = LinearAttention(dim, num_heads)
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim)

    def forward(self, x: torch.Tensor, kv: torch.Tensor | None = None) -> torch.Tensor:
        """x [B*S, N, C]; kv [B, M, C] for cross-attention, shared by S consecutive samples of x."""
        q = self.norm1(x)
        if kv is None:
            k = v = q
        else:
            k = v = self.norm1(kv) if self.norm_kv else kv
        x = self.ls1.residual(x, self.attn(q, k, v))
        return self.ls2.residual(x, self.mlp(self.norm2(x)))


class SideViewAttention(nn.Module):
    """SVA on the DINOv2 taps (the reference's ``CrossVITDecoder``) and the upsampler to 1/8 resolution.

    Reference view: r0 = tap0; r_i = LN_i(p_i * SelfBlock_i(r_{i-1}) + tap_i). Source view:
    s0 = Cross_0(tap0, kv=r0); s_i = Cross_i(LN_i(p_i * s_{i-1} + tap_i), kv=r_i). Output per view,
    then Conv3x3 -> BN -> SiLU and two stride-2 transposed convs: 4x the token grid, ``out_ch`` channels.
    """

    def __init__(self, dim: int = 768, num_heads: int = 12, num_taps: int = 3, out_ch: int = 64,
                 mlp_ratio: float = 4.0, prev_value: float = 0.5):
        super().__init__()
        self.self_attn_blocks = nn.ModuleList(
            [LinearAttentionBlock(dim, num_heads, mlp_ratio) for _ in range(num_taps - 1)]
        )
        self.cross_attn_blocks = nn.ModuleList(
            [LinearAttentionBlock(dim, num_heads, mlp_ratio) for _ in range(num_taps)]
        )
        self.norm_layers = nn.ModuleList([nn.LayerNorm(dim, eps=1e-6) for _ in range(num_taps - 1)])
        self.prev_values = nn.ParameterList(
            [nn.Parameter(torch.tensor(float(prev_value))) for _ in range(num_taps - 1)]
        )
        self.proj = nn.Sequential(nn.Conv2d(dim, out_ch * 4, 3, padding=1), nn.BatchNorm2d(out_ch * 4), nn.SiLU())
        self.upsampler0 = nn.Sequential(
            nn.ConvTranspose2d(out_ch * 4, out_ch * 2, 4, stride=2, padding=1), nn.BatchNorm2d(out_ch * 2), nn.SiLU()
        )
        self.upsampler1 = nn.Sequential(
            nn.ConvTranspose2d(out_ch * 2, out_ch, 4, stride=2, padding=1), nn.BatchNorm2d(out_ch), nn.SiLU()
        )

    def attend(self, taps: list[torch.Tensor]) -> torch.Tensor:
        """taps: each [B, V, L, C] (view 0 = reference) -> [B, V, L, C]."""
        ref = [taps[0][:, 0]]
        for i, block in enumerate(self.self_attn_blocks):
            ref.append(self.norm_layers[i](self.prev_values[i] * block(ref[-1]) + taps[i + 1][:, 0]))
        V = taps[0].shape[1]
        if V == 1:
            return ref[-1][:, None]
        # All source views at once, folded into the batch.
        B, _, L, C = taps[0].shape
        def src_tap(i):  # noqa: E306
            return taps[i][:, 1:].reshape(B * (V - 1), L, C)
        # every source view of a sample attends to the same reference keys/values (computed once)
        src = self.cross_attn_blocks[0](src_tap(0), ref[0])
        for i in range(1, len(self.cross_attn_blocks)):
            query = self.norm_layers[i - 1](self.prev_values[i - 1] * src + src_tap(i))
            src = self.cross_attn_blocks[i](query, ref[i])
        return torch.cat([ref[-1][:, None], src.reshape(B, V - 1, L, C)], dim=1)

    def upsample(self, tokens: torch.Tensor, hw: tuple[int, int]) -> torch.Tensor:
        """[N, L, C] tokens on an h x w grid -> [N, out_ch, 4h, 4w]."""
        N, _, C = tokens.shape
        x = tokens.reshape(N, hw[0], hw[1], C).permute(0, 3, 1, 2)
        forms = prepared.forms(self)
        if forms is None:
            return self.upsampler1(self.upsampler0(self.proj(x)))
        for (w, b), (conv, _, _) in zip(forms, (self.proj, self.upsampler0, self.upsampler1)):
            if isinstance(conv, nn.ConvTranspose2d):  # prepared inference: BatchNorm folded, SiLU in place
                x = F.conv_transpose2d(x, w, b, conv.stride, conv.padding)
            else:
                x = F.conv2d(x, w, b, conv.stride, conv.padding)
            x = F.silu(x, inplace=True)
        return x

    inference_sources = ("proj", "upsampler0", "upsampler1")

    def build_inference_forms(self) -> list:
        """The projection and upsampler convolutions with their BatchNorm folded in (:mod:`.inference`)."""
        return [fused_conv_bn(seq[0], seq[1], memory_format=torch.contiguous_format)
                for seq in (self.proj, self.upsampler0, self.upsampler1)]

    def forward(self, taps: list[torch.Tensor], hw: tuple[int, int]) -> torch.Tensor:
        """taps: each [B, V, L, C] -> [B*V, out_ch, 4h, 4w] (batch-major)."""
        x = self.attend(taps)
        B, V, L, C = x.shape
        return self.upsample(x.reshape(B * V, L, C), hw)
