"""Per-stage cross-entropy loss over depth bins."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def stage_ce_loss(logits: torch.Tensor, hypotheses: torch.Tensor, depth_gt: torch.Tensor,
                  mask: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of [B,D,H,W] logits against the GT depth's bin.

    Hypotheses are flipped to ascending depth (inverse sampling gives descending); bins are bounded
    by mid-points, the first/last extended by half a gap; pixels outside the bins or masked out are
    ignored. A stage with no valid pixel gives a zero loss that still has a gradient path (the
    reference returns NaN).
    """
    d = torch.flip(hypotheses, dims=[1])
    logits = torch.flip(logits.float(), dims=[1])
    half = torch.abs(d[:, 1:] - d[:, :-1]) / 2
    half = torch.cat([half, half[:, -1:]], dim=1)
    gt = depth_gt[:, None]
    in_range = (gt >= d[:, :1] - half[:, :1]) & (gt <= d[:, -1:] + half[:, -1:])
    valid = in_range[:, 0] & (mask > 0.5)
    target = ((d + half) <= gt).sum(dim=1).clamp(max=d.shape[1] - 1)
    if not valid.any():
        return logits.sum() * 0.0
    return F.cross_entropy(logits.permute(0, 2, 3, 1)[valid], target[valid])


def cascade_loss(outputs: dict, depth_gt: dict, masks: dict, weights=(1.0, 1.0, 1.0, 1.0)):
    """Sum of the per-stage losses; returns (total, {stage: loss})."""
    per_stage = {}
    for i, w in enumerate(weights):
        key = f"stage{i + 1}"
        if key in outputs:
            o = outputs[key]
            per_stage[key] = w * stage_ce_loss(o["prob_volume_pre"], o["depth_values"], depth_gt[key], masks[key])
    return sum(per_stage.values()), per_stage
