"""Cost Volume Transformer at stage 1 (paper sec. 3.3): frustoconical positional encoding,
patchify (2,4,4), Post-LN transformer blocks with adaptive attention scaling, unpatchify.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models.attention import softmax_attention
from mvsformerpp.models.layers import LayerNorm3D, gelu_
from mvsformerpp.utils.precision import autocast_enabled, cpu_attention_in_bf16

# Mean stage-1 token count over the reference's 25 training scales; the reference truncates 12185.6.
TRAIN_AVG_TOKENS = 12185


def adaptive_attention_scale(head_dim: int, num_tokens: int, train_avg_tokens: int = TRAIN_AVG_TOKENS) -> float:
    """AAS: head_dim^-0.5 * log_{n_train}(L), keeping attention entropy stable across resolutions.

    In a graph being exported with a symbolic token count, the scale is a graph value (a float32 scalar
    tensor, computed in float64 as here)."""
    if isinstance(num_tokens, torch.SymInt):
        log_n = torch.log(torch.scalar_tensor(num_tokens, dtype=torch.float64))
        return (head_dim ** -0.5 * log_n / math.log(train_avg_tokens)).to(torch.float32)
    return head_dim ** -0.5 * math.log(num_tokens) / math.log(train_avg_tokens)


def frustum_coordinates(K: torch.Tensor, hypotheses: torch.Tensor, depth_min: torch.Tensor,
                        depth_max: torch.Tensor) -> torch.Tensor:
    """Normalised camera-frame coordinates of every (hypothesis, pixel) of the stage-1 volume (FPE).

    K: [B,3,3] stage-1 intrinsics; hypotheses: [B,D,H,W]. P = K^-1 [x,y,1]^T d for integer pixels;
    X and Y min-max normalised over the whole tensor (all samples), Z clamped to [dmin, dmax] and
    normalised. Returns [B, 3, D, H, W] in [0, 1].
    """
    return frustum_coordinates_from_inverse(torch.inverse(K.float()), hypotheses, depth_min, depth_max)


def frustum_coordinates_from_inverse(K_inv: torch.Tensor, hypotheses: torch.Tensor, depth_min: torch.Tensor,
                                     depth_max: torch.Tensor) -> torch.Tensor:
    """:func:`frustum_coordinates` from the inverse intrinsics ``K_inv`` [B, 3, 3] (a portable graph has no
    matrix inverse: its caller gives it)."""
    B, D, H, W = hypotheses.shape
    y, x = torch.meshgrid(
        torch.arange(H, dtype=torch.float32, device=K_inv.device),
        torch.arange(W, dtype=torch.float32, device=K_inv.device),
        indexing="ij",
    )
    xyz = torch.stack((x.reshape(-1), y.reshape(-1), torch.ones_like(x).reshape(-1)))
    rays = K_inv @ xyz  # [B, 3, HW]
    pts = rays[:, :, None] * hypotheses.reshape(B, 1, D, H * W)  # [B, 3, D, HW]
    px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
    nx = (px - px.min()) / (px.max() - px.min() + 1e-5)
    ny = (py - py.min()) / (py.max() - py.min() + 1e-5)
    nz = (torch.clamp(pz, depth_min, depth_max) - depth_min) / (depth_max - depth_min + 1e-5)
    return torch.stack((nx, ny, nz), dim=1).reshape(B, 3, D, H, W)


def sine_encoding_3d(coords: torch.Tensor, channels: int, rescale: float = 4.0) -> torch.Tensor:
    """[B,3,D,H,W] coordinates in [0,1] -> [B, 3*channels, D, H, W]: per axis sin/cos(4 a w_i), w_i = 10000^(-2i/C)."""
    B, _, D, H, W = coords.shape
    div = torch.exp(torch.arange(0, channels, 2, device=coords.device).float() * (-math.log(10000.0) / channels))
    out = []
    for axis in range(3):
        a = coords[:, axis].reshape(B, 1, -1) * rescale * div[None, :, None]  # [B, C/2, DHW]
        pe = torch.stack((torch.sin(a), torch.cos(a)), dim=2).reshape(B, channels, -1)
        out.append(pe)
    return torch.cat(out, dim=1).reshape(B, 3 * channels, D, H, W)


def local_evidence(volume: torch.Tensor, box: int) -> torch.Tensor:
    """What the cost volume itself says about each pixel's depth, aggregated over its neighbours.

    [B, G, D, H, W] group correlations -> [B, 1, D, H, W]: the sum over groups, averaged over a box x box
    window of cells at every hypothesis (classic window matching; zero padding, counted), then
    standardised over the hypotheses at each pixel (zero mean, unit deviation), so that its scale does
    not depend on the features' magnitude. Added to the transformer's logits it gives stage 1 per-cell
    evidence that the patch tokens (4 x 4 cells each, decoded patch by patch) blur.
    """
    score = volume.float().sum(1)  # [B, D, H, W]
    if box > 1:
        score = F.avg_pool2d(score, box, 1, box // 2, count_include_pad=True)
    score = score - score.mean(1, keepdim=True)
    return (score / (score.std(1, keepdim=True) + 1e-6))[:, None]


class CVTAttention(nn.Module):
    """Multi-head softmax self-attention with AAS as the scale."""

    def __init__(self, dim: int, num_heads: int, train_avg_tokens: int = TRAIN_AVG_TOKENS):
        super().__init__()
        self.num_heads, self.train_avg_tokens = num_heads, train_avg_tokens
        self.qkv = nn.Linear(dim, dim * 3, bias=False)
        self.proj = nn.Linear(dim, dim)
        self.backend = "sdpa"
        self.bf16 = False
        """Softmax attention in bf16 inside an fp32 forward (``MVSFormerPP.set_attention_precision``)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, N, C = x.shape
        hd = C // self.num_heads
        qkv = self.qkv(x).reshape(B, N, 3, self.num_heads, hd).permute(2, 0, 3, 1, 4)
        scale = adaptive_attention_scale(hd, N, self.train_avg_tokens)
        in_bf16 = self.bf16 and qkv.dtype == torch.float32  # (under an autocast it follows the autocast)
        out = softmax_attention(*(qkv.bfloat16() if in_bf16 else qkv), scale=scale, backend=self.backend)
        if in_bf16:
            out = out.float()
        return self.proj(out.transpose(1, 2).reshape(B, N, C))


class FFN(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.linear1 = nn.Linear(dim, hidden)
        self.linear2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.linear2(gelu_(self.linear1(x)))


class CVTBlock(nn.Module):
    """Post-LN block with scalar gammas: x = LN1(x + g1 Attn(x)); x = LN2(x + g2 FFN(x))."""

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float = 4.0, train_avg_tokens: int = TRAIN_AVG_TOKENS):
        super().__init__()
        self.attn = CVTAttention(dim, num_heads, train_avg_tokens)
        self.gamma1 = nn.Parameter(torch.tensor(1.0))
        self.norm1 = nn.LayerNorm(dim)
        self.ffn = FFN(dim, int(dim * mlp_ratio))
        self.gamma2 = nn.Parameter(torch.tensor(1.0))
        self.norm2 = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.norm1(x + self.gamma1 * self.attn(x))
        return self.norm2(x + self.gamma2 * self.ffn(x))


class CostVolumeTransformer(nn.Module):
    """[B, C, D, H, W] cost volume (+ FPE) -> logits [B, 1, D, H, W]."""

    def __init__(self, in_ch: int = 8, mid_ch: int = 64, num_heads: int = 4, num_layers: int = 6,
                 patch=(2, 4, 4), mlp_ratio: float = 4.0, train_avg_tokens: int = TRAIN_AVG_TOKENS,
                 local_weight: float = 0.0, local_box: int = 9, local_gate: tuple[float, float] | None = None,
                 shifts: int = 1):
        super().__init__()
        if not 1 <= int(shifts) <= min(patch[1:]):
            raise ValueError(f"cvt_shifts must be 1 .. {min(patch[1:])} (the token patch's side in cells), "
                             f"got {shifts}")
        self.shifts = int(shifts)
        self.random_placement = False  # training only: see TrainConfig.cvt_random_placement
        self.average_in_training = False  # training only: see TrainConfig.cvt_train_shifts
        if local_box < 1 or local_box % 2 == 0:
            raise ValueError(f"local_evidence_box must be an odd number of cells >= 1, got {local_box}")
        if local_gate is not None and not (len(local_gate) == 2 and local_gate[0] < local_gate[1]):
            raise ValueError(f"local_evidence_gate must be two numbers a < b, got {local_gate}")
        self.local_gate = None if local_gate is None else (float(local_gate[0]), float(local_gate[1]))
        self.in_ch = in_ch
        self.local_weight, self.local_box = float(local_weight), int(local_box)
        self.pe_proj = nn.Conv3d(in_ch * 3, in_ch, 1, bias=False)
        self.down = nn.Sequential(nn.Conv3d(in_ch, mid_ch, patch, stride=patch), LayerNorm3D(mid_ch))
        self.attention_layers = nn.ModuleList(
            [CVTBlock(mid_ch, num_heads, mlp_ratio, train_avg_tokens) for _ in range(num_layers)]
        )
        self.up = nn.Sequential(nn.ConvTranspose3d(mid_ch, in_ch, patch, stride=patch), LayerNorm3D(in_ch))
        self.prob = nn.Conv3d(in_ch, 1, 1)

    def forward(self, volume: torch.Tensor, coords: torch.Tensor | None = None) -> torch.Tensor:
        if volume.device.type == "cpu" and autocast_enabled("cpu") and not cpu_attention_in_bf16():
            # without AMX, PyTorch's CPU attention has no faster kernel in bf16 (the block runs 15 % slower
            # in it): there this block runs in fp32 whatever the autocast; with AMX and on GPUs it follows it
            with torch.autocast("cpu", enabled=False):
                return self._forward(volume.float(), None if coords is None else coords.float())
        return self._forward(volume, coords)

    def _forward(self, volume: torch.Tensor, coords: torch.Tensor | None) -> torch.Tensor:
        evidence = local_evidence(volume, self.local_box) if self.local_weight else None
        if evidence is not None and self.local_gate is not None:
            a, b = self.local_gate
            evidence = evidence * ((evidence.amax(2, keepdim=True) - a) / (b - a)).clamp_(0, 1)
        if coords is not None:
            volume = volume + self.pe_proj(sine_encoding_3d(coords, self.in_ch))
        if self.training and self.random_placement:
            ph, pw = self.down[0].kernel_size[1:]
            logits = self._placed_logits(volume, int(torch.randint(ph, ())), int(torch.randint(pw, ())))
        elif self.shifts == 1 or (self.training and not self.average_in_training):
            logits = self._logits(volume)
        else:
            logits = self._shift_averaged(volume)
        return logits if evidence is None else logits.add_(evidence, alpha=self.local_weight)

    def _logits(self, volume: torch.Tensor) -> torch.Tensor:
        x = self.down(volume)
        B, C, d, h, w = x.shape
        tokens = x.permute(0, 3, 4, 2, 1).reshape(B, h * w * d, C)  # (h, w, d) order, as the reference
        for layer in self.attention_layers:
            tokens = layer(tokens)
        x = tokens.reshape(B, h, w, d, C).permute(0, 4, 3, 1, 2)
        return self.prob(self.up(x))

    def _placed_logits(self, volume: torch.Tensor, sy: int, sx: int) -> torch.Tensor:
        """The logits with the token grid starting ``sy``, ``sx`` cells up and left of the volume (its
        border cells repeated to fill the patches), cropped back onto the volume's cells."""
        if not (sy or sx):
            return self._logits(volume)
        ph, pw = self.down[0].kernel_size[1:]
        H, W = volume.shape[-2:]
        padded = F.pad(volume, (sx, (pw - sx) % pw, sy, (ph - sy) % ph, 0, 0), mode="replicate")
        return self._logits(padded)[..., sy:sy + H, sx:sx + W]

    def _shift_averaged(self, volume: torch.Tensor) -> torch.Tensor:
        """The mean of the logits over ``shifts`` placements of the token grid. Each token decodes its own
        4x4-cell patch, so one placement's logits step at the patch borders (the depth maps' 32-pixel block
        pattern: docs/model-card.md, "Block pattern"); placement i starts the grid i * patch / shifts cells
        up and left of the volume and is cropped back (:meth:`_placed_logits`)."""
        ph, pw = self.down[0].kernel_size[1:]
        total = None
        for i in range(self.shifts):
            logits = self._placed_logits(volume, i * ph // self.shifts, i * pw // self.shifts)
            total = logits if total is None else total.add_(logits)
        return total.div_(self.shifts)
