"""Inverse-depth hypotheses of the cascade: uniform in 1/d, ordered far -> near."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def initial_hypotheses(depth_values: torch.Tensor, num: int, H: int, W: int) -> torch.Tensor:
    """Stage 1: d_k = 1 / (1/dmax + (1/dmin - 1/dmax) k/(D-1)), k = 0..D-1, broadcast to [B, D, H, W].

    dmin, dmax = depth_values[:, 0], depth_values[:, -1].
    """
    inv_min = 1.0 / depth_values[:, 0]
    inv_max = 1.0 / depth_values[:, -1]
    steps = torch.arange(num, device=depth_values.device, dtype=depth_values.dtype).reshape(1, -1, 1, 1)
    steps = steps.repeat(1, 1, H, W) / (num - 1)
    inv = inv_max[:, None, None, None] + (inv_min - inv_max)[:, None, None, None] * steps
    return 1.0 / inv


def plane_step(hypotheses: torch.Tensor) -> torch.Tensor:
    """[B, h, w] inverse-depth spacing of a stage's planes (uniform in 1/d), the unit of the next window."""
    return 1.0 / hypotheses[:, 2] - 1.0 / hypotheses[:, 1]


def refined_hypotheses(depth: torch.Tensor, prev_hypotheses: torch.Tensor, num: int, ratio: float,
                       H: int, W: int, min_inverse: torch.Tensor | None = None) -> torch.Tensor:
    """Stages 2-4: ``num`` hypotheses uniform in 1/d around the previous estimate, upsampled x2.

    The half-width is ``ratio`` times the previous stage's inverse-depth step (1/d_2 - 1/d_1).
    ``min_inverse`` [B] (typically 1/(10 dmax)) keeps every inverse hypothesis positive: the
    reference has no such clamp and produces negative or huge depths for wide depth ranges. The
    window is shifted up, keeping its width, only where it would cross the bound, so ordinary ranges
    are untouched.
    """
    step = plane_step(prev_hypotheses)
    inv_near = 1.0 / depth + ratio * step
    inv_far = 1.0 / depth - ratio * step
    if min_inverse is not None:
        shift = (min_inverse[:, None, None] - inv_far).clamp(min=0)
        inv_far, inv_near = inv_far + shift, inv_near + shift
    steps = torch.arange(num, device=depth.device, dtype=depth.dtype).reshape(1, -1, 1, 1)
    steps = steps.repeat(1, 1, H // 2, W // 2) / (num - 1)
    inv = inv_far[:, None] + (inv_near - inv_far)[:, None] * steps
    inv = F.interpolate(inv[:, None], [num, H, W], mode="trilinear", align_corners=True)[:, 0]
    return 1.0 / inv
