"""The ``dynamic`` fusion method: the dynamic consistency check of DPCD (Yan et al. 2020, "Dense Hybrid
Recurrent Multi-view Stereo Net with Dynamic Consistency Checking", Sec. 3.4), as the reference fuses
Tanks and Temples.

At level k = 2 .. S (S source views) a source agrees when the reprojection error is below
k / ``dist_base`` pixels and the relative depth error |d_ref - d| / d_ref below k / ``rel_diff_base``; a
pixel is kept when some level has at least k agreeing sources. The loosest level decides which source
depths are averaged. Sources keep all their depths.
"""

from __future__ import annotations

import torch

from mvsformerpp.fusion.core import ReprojectionKernel


class Kernel(ReprojectionKernel):
    def consistent(self, err: torch.Tensor, dr: torch.Tensor, d: torch.Tensor,
                   valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cfg = self.cfg
        rel = (dr - d).abs() / d
        S = err.shape[0]
        keep = torch.zeros_like(d, dtype=torch.bool)
        consistent = torch.zeros_like(valid)
        for k in range(2, max(S, 2) + 1):
            level = valid & (err < k / cfg.dist_base) & (rel < k / cfg.rel_diff_base)
            keep |= level.sum(0) >= k
            consistent = level  # the loosest level decides which depths are averaged
        return keep, consistent
