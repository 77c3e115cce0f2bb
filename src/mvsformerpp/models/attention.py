"""Attention kernels behind one switch.

* Softmax attention (DINOv2, the Cost Volume Transformer): ``"sdpa"`` (PyTorch's fused
  ``scaled_dot_product_attention``, the default), ``"flash"`` (FlashAttention-2, CUDA with fp16/bf16,
  used when the ``flash_attn`` package imports) and ``"eager"`` (the textbook formula, a reference).
  ``"auto"`` picks flash where it can run and SDPA elsewhere.
* ``"chunked"``: the textbook formula over a fixed number of query chunks (:data:`QUERY_CHUNKS`), in plain
  matrix products and a softmax: the form of the portable (ONNX) graphs, whose token counts are symbolic
  and whose runtimes have no memory-efficient kernel: a cost volume of 1152x1536 photos has 27 648 tokens,
  whose whole attention matrix would take 12 GB.
* Linear attention (Side View Attention and FMT): phi(u) = elu(u) + 1, always in fp32.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

BACKENDS = ("auto", "sdpa", "flash", "eager", "chunked")
QUERY_CHUNKS = 16
"""Query chunks of the ``chunked`` backend: each holds 1/16 of the attention matrix."""


@functools.lru_cache(maxsize=1)
def _flash_attn_func():
    try:
        from flash_attn import flash_attn_func
    except Exception:  # not installed, or built for another torch/CUDA
        return None
    return flash_attn_func


def flash_available() -> bool:
    return _flash_attn_func() is not None


def _flash_usable(q: torch.Tensor) -> bool:
    return q.is_cuda and q.dtype in (torch.float16, torch.bfloat16) and q.shape[-1] <= 256 and flash_available()


def softmax_attention(
    q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, scale: float | None = None, backend: str = "sdpa"
) -> torch.Tensor:
    """softmax(scale * q k^T) v for q, k, v of shape [B, heads, L, head_dim].

    ``scale`` defaults to head_dim^-0.5. ``backend="flash"`` raises if FlashAttention cannot run on
    these tensors (CUDA, fp16/bf16, flash_attn installed); ``"auto"`` falls back to SDPA instead.
    """
    if scale is None:
        scale = q.shape[-1] ** -0.5
    if backend == "auto":
        backend = "flash" if _flash_usable(q) else "sdpa"
    if backend == "sdpa":
        return F.scaled_dot_product_attention(q, k, v, scale=scale)
    if backend == "eager":
        attn = torch.softmax((q * scale) @ k.transpose(-2, -1), dim=-1)
        return attn @ v
    if backend == "chunked":
        return chunked_attention(q, k, v, scale)
    if backend == "flash":
        if not _flash_usable(q):
            raise RuntimeError(
                "flash attention needs the flash_attn package, a CUDA device and fp16/bf16 tensors "
                "(install mvsformerpp[flash] and run with --precision bf16), or use backend 'sdpa'"
            )
        out = _flash_attn_func()(q.transpose(1, 2), k.transpose(1, 2), v.transpose(1, 2), softmax_scale=scale)
        return out.transpose(1, 2)
    raise ValueError(f"unknown attention backend {backend!r}; choose one of {BACKENDS}")


def chunked_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, scale, chunks: int = QUERY_CHUNKS):
    """softmax(scale * q k^T) v computed for ``chunks`` consecutive slices of the queries, one after the
    other (the same result; a slice may be empty when there are fewer queries than chunks). ``scale``: a
    number or a scalar tensor (a graph value in an exported graph)."""
    n = q.shape[-2]
    step = (n + chunks - 1) // chunks
    kt = k.transpose(-2, -1)
    parts = [torch.softmax((q[..., i * step:(i + 1) * step, :] @ kt) * scale, dim=-1) @ v for i in range(chunks)]
    return torch.cat(parts, dim=-2)


def linear_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Linear attention (Katharopoulos et al. 2020) as SVA uses it, for [B, L, heads, head_dim] inputs.

    out_i = phi(q_i)^T [sum_j phi(k_j) v_j^T] / (phi(q_i)^T sum_j phi(k_j) + eps), phi = elu + 1.
    Computed in float32 whatever the surrounding autocast, as the reference does. Keys and values may
    have a batch B that divides the queries' batch B*S: query sample b*S + s then attends to key
    sample b (S query sets sharing one key set, whose summaries are computed once).
    """
    with torch.autocast(device_type=q.device.type, enabled=False):
        q = F.elu(q.float()) + 1
        k = F.elu(k.float()) + 1
        v = v.float()
        kv = torch.einsum("nshd,nshm->nhmd", k, v)
        ksum = k.sum(dim=1)
        if k.shape[0] != q.shape[0]:
            S = q.shape[0] // k.shape[0]
            kv, ksum = kv.repeat_interleave(S, dim=0), ksum.repeat_interleave(S, dim=0)
        z = 1 / (torch.einsum("nlhd,nhd->nlh", q, ksum) + eps)
        return torch.einsum("nlhd,nhmd,nlh->nlhm", q, kv, z)
