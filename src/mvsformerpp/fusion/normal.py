"""The ``normal`` fusion method: fixed reprojection thresholds (the reference's ``filter_depth``).

A reference depth is consistent with a source view when it reprojects within ``disp_threshold`` pixels
and its depth comes back within ``rel_depth_threshold`` relative error, |d_ref - d| / max(d_ref, d); it is
kept when ``num_consistent`` sources agree. Sources see only their own confident depths.
"""

from __future__ import annotations

import torch

from mvsformerpp.fusion.core import ReprojectionKernel


class Kernel(ReprojectionKernel):
    filter_sources = True

    def consistent(self, err: torch.Tensor, dr: torch.Tensor, d: torch.Tensor,
                   valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cfg = self.cfg
        rel = (dr - d).abs() / torch.maximum(dr, d)
        consistent = valid & (err < cfg.disp_threshold) & (rel < cfg.rel_depth_threshold)
        return consistent.sum(0) >= cfg.num_consistent, consistent
