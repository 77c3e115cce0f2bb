"""The ``gipuma`` fusion method: fusibile's rule (Galliani et al. 2015), as the reference fuses DTU.

Each reference pixel is lifted to a world point and projected into the source views; a source agrees
when its confident depth at the nearest pixel gives a disparity (f x baseline / depth) within
``disp_threshold`` of the point's. With ``num_consistent`` agreeing sources the point is the mean of the
reference point and the agreeing sources' points (colours likewise), and the source pixels it used are
consumed: they start no point of their own when their view is the reference.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from mvsformerpp.fusion.config import FusionConfig
from mvsformerpp.fusion.core import FusionKernel, FusionView, confident_depth, pixel_centres
from mvsformerpp.geometry.camera import backproject, project


class ConsumedPixels:
    """Marks of source pixels already merged into a point, for the views not yet fused.

    ``marks[j]`` is view j's ``[H, W]`` bool mask while a reference is being fused; between reference
    views the masks are kept bit-packed (1 bit per pixel) and a view's mask is dropped once the view
    itself has been a reference (nothing reads it afterwards).
    """

    def __init__(self, views):
        self.views = views
        self._packed: dict[int, np.ndarray] = {}
        self._open: dict[int, torch.Tensor] = {}
        self._done: set[int] = set()

    def __getitem__(self, j: int) -> torch.Tensor:
        if j not in self._open:
            depth = self.views[j].depth
            if j in self._packed:
                bits = np.unpackbits(self._packed.pop(j), count=depth.numel()).astype(bool)
                self._open[j] = torch.from_numpy(bits).reshape(depth.shape).to(depth.device)
            else:
                self._open[j] = torch.zeros_like(depth, dtype=torch.bool)
        return self._open[j]

    def finish(self, r: int) -> None:
        """Reference view r is fused: pack the marks made meanwhile, forget view r's."""
        self._done.add(r)
        for j, mask in self._open.items():
            if j not in self._done:
                self._packed[j] = np.packbits(mask.reshape(-1).cpu().numpy())
        self._open.clear()
        self._packed.pop(r, None)


class Kernel(FusionKernel):
    def __init__(self, views: Sequence[FusionView], cfg: FusionConfig):
        super().__init__(views, cfg)
        self.used = ConsumedPixels(views)

    def taken(self, r: int) -> torch.Tensor:
        return self.used[r]

    def finish(self, r: int) -> None:
        self.used.finish(r)

    def fuse(self, r: int, sources: list[int], idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        views, cfg = self.views, self.cfg
        ref = views[r]
        H, W = ref.depth.shape
        u, v = pixel_centres(H, W, idx)
        d = ref.depth.reshape(-1)[idx]
        X = backproject(ref.K, ref.E, u, v, d)
        f = ref.K[0, 0]
        sum_x = X.clone()
        sum_rgb = ref.image.reshape(-1, 3)[idx].float()
        count = torch.zeros_like(d, dtype=torch.int64)
        hits = []
        for j in sources:
            src = views[j]
            Hs, Ws = src.depth.shape
            us, vs, z = project(src.K, src.E, X)
            inside = (us >= 0) & (us < Ws) & (vs >= 0) & (vs < Hs) & (z > 0)
            ui = us.clamp(0, Ws - 1).floor().long()
            vi = vs.clamp(0, Hs - 1).floor().long()
            flat = vi * Ws + ui
            dj = confident_depth(src, cfg).reshape(-1)[flat]
            baseline = torch.linalg.norm(ref.center - src.center)
            disp_diff = (f * baseline * (1 / z.clamp(min=1e-12) - 1 / dj.clamp(min=1e-12))).abs()
            ok = inside & (dj > 0) & (disp_diff < cfg.disp_threshold)
            Y = backproject(src.K, src.E, ui.float() + 0.5, vi.float() + 0.5, dj)
            sum_x += Y * ok[:, None]
            sum_rgb += src.image.reshape(-1, 3)[flat].float() * ok[:, None]
            count += ok
            hits.append((j, flat, ok))
        keep = count >= cfg.num_consistent
        for j, flat, ok in hits:
            self.used[j].view(-1)[flat[ok & keep]] = True
        n = (count + 1).to(X.dtype)[:, None]
        return (sum_x / n)[keep], (sum_rgb / n)[keep]
