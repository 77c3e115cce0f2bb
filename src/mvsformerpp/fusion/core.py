"""Depth-map fusion in PyTorch: the reference's ``normal``, ``dynamic`` and ``gipuma`` filters.

Pixel convention (one for all three, fixing the reference's half-pixel mix-up): pixel
``(x, y)`` covers ``[x, x+1) x [y, y+1)`` of the continuous image coordinates that K maps to, so its
centre is ``(x + 0.5, y + 0.5)``; maps are sampled at continuous coordinates with
``grid_sample(align_corners=False)``, whose pixel centres sit at the same +0.5. Everything runs on the
caller's device, reference pixels in chunks to bound memory.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.fusion.config import FusionConfig
from mvsformerpp.geometry.camera import backproject, project


@dataclass
class FusionView:
    """One view at its depth map's resolution."""

    depth: torch.Tensor  # [H, W], 0 = no estimate
    confidence: torch.Tensor  # [H, W] in [0, 1]
    K: torch.Tensor  # [3, 3] for this resolution
    E: torch.Tensor  # [4, 4] world-to-camera
    image: torch.Tensor  # [H, W, 3] uint8

    @property
    def center(self) -> torch.Tensor:
        return -self.E[:3, :3].T @ self.E[:3, 3]


def sample(values: torch.Tensor, u: torch.Tensor, v: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """Sample [H,W] or [H,W,C] at continuous coordinates; zeros outside the image."""
    H, W = values.shape[:2]
    img = values.reshape(H, W, -1).permute(2, 0, 1)[None].float()
    grid = torch.stack((2 * u / W - 1, 2 * v / H - 1), dim=-1).reshape(1, 1, -1, 2).to(img.dtype)
    out = F.grid_sample(img, grid, mode=mode, padding_mode="zeros", align_corners=False)[0, :, 0]
    return out.T.squeeze(1) if values.ndim == 2 else out.T


def _pixel_centres(H: int, W: int, idx: torch.Tensor):
    return (idx % W).to(torch.float32) + 0.5, (idx // W).to(torch.float32) + 0.5


def _reprojection_errors(ref: FusionView, srcs: list[FusionView], src_depths, u, v, d):
    """Project ref pixels into each source, sample its depth, lift and project back.

    Returns per source [S, N]: pixel error, reprojected depth in the reference, validity.
    """
    X = backproject(ref.K, ref.E, u, v, d)
    errs, depths, valid = [], [], []
    for src, sdepth in zip(srcs, src_depths):
        H, W = sdepth.shape
        us, vs, _ = project(src.K, src.E, X)
        ds = sample(sdepth, us, vs)
        ok = (ds > 0) & (us >= 0) & (us < W) & (vs >= 0) & (vs < H)
        Y = backproject(src.K, src.E, us, vs, ds)
        ur, vr, dr = project(ref.K, ref.E, Y)
        errs.append(torch.hypot(ur - u, vr - v))
        depths.append(dr)
        valid.append(ok & (dr > 0))
    return torch.stack(errs), torch.stack(depths), torch.stack(valid)


def _confident_depth(view: FusionView, cfg: FusionConfig) -> torch.Tensor:
    """The view's depth with the pixels at or below the confidence threshold set to 0 (no estimate):
    what ``normal`` and ``gipuma`` see of a source view."""
    return torch.where(view.confidence > cfg.conf_threshold, view.depth, torch.zeros_like(view.depth))


def _fuse_reprojection(ref, srcs, cfg: FusionConfig, idx):
    """normal / dynamic filters for the reference pixels ``idx``; returns (kept idx, fused depth)."""
    H, W = ref.depth.shape
    u, v = _pixel_centres(H, W, idx)
    d = ref.depth.reshape(-1)[idx]
    if cfg.method == "normal":  # sources are filtered by their own confidence first
        src_depths = [_confident_depth(s, cfg) for s in srcs]
    else:
        src_depths = [s.depth for s in srcs]
    err, dr, valid = _reprojection_errors(ref, srcs, src_depths, u, v, d)
    if cfg.method == "normal":
        rel = (dr - d).abs() / torch.maximum(dr, d)
        consistent = valid & (err < cfg.disp_threshold) & (rel < cfg.rel_depth_threshold)
        keep = consistent.sum(0) >= cfg.num_consistent
    else:  # dynamic consistency check (Yan et al. 2020), levels k = 2..S
        rel = (dr - d).abs() / d
        S = len(srcs)
        keep = torch.zeros_like(d, dtype=torch.bool)
        consistent = torch.zeros_like(valid)
        for k in range(2, max(S, 2) + 1):
            level = valid & (err < k / cfg.dist_base) & (rel < k / cfg.rel_diff_base)
            keep |= level.sum(0) >= k
            consistent = level  # the loosest level decides which depths are averaged
    fused = (d + (dr * consistent).sum(0)) / (1 + consistent.sum(0))
    return idx[keep], fused[keep]


def consistent_pixels(ref: FusionView, srcs: list[FusionView], cfg: FusionConfig) -> torch.Tensor:
    """Flat indices of the reference pixels with depth that the ``normal`` or ``dynamic`` filter of ``cfg`` keeps
    against ``srcs`` (what fusion would fuse; the teacher labels of ``tools/teacher_labels.py``)."""
    idx = torch.nonzero((ref.depth.reshape(-1) > 0) & (ref.confidence.reshape(-1) > cfg.conf_threshold)).squeeze(1)
    return _fuse_reprojection(ref, srcs, cfg, idx)[0]


def _fuse_gipuma_ref(views, r, candidates, cfg: FusionConfig, idx, used):
    """fusibile's rule for reference pixels ``idx`` of view r; marks the pixels it consumes in ``used``."""
    ref = views[r]
    H, W = ref.depth.shape
    u, v = _pixel_centres(H, W, idx)
    d = ref.depth.reshape(-1)[idx]
    X = backproject(ref.K, ref.E, u, v, d)
    f = ref.K[0, 0]
    sum_x = X.clone()
    sum_rgb = ref.image.reshape(-1, 3)[idx].float()
    count = torch.zeros_like(d, dtype=torch.int64)
    hits = []
    for j in candidates:
        src = views[j]
        Hs, Ws = src.depth.shape
        us, vs, z = project(src.K, src.E, X)
        inside = (us >= 0) & (us < Ws) & (vs >= 0) & (vs < Hs) & (z > 0)
        ui = us.clamp(0, Ws - 1).floor().long()
        vi = vs.clamp(0, Hs - 1).floor().long()
        flat = vi * Ws + ui
        dj = _confident_depth(src, cfg).reshape(-1)[flat]
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
        used[j].view(-1)[flat[ok & keep]] = True
    n = (count + 1).to(X.dtype)[:, None]
    return (sum_x / n)[keep], (sum_rgb / n)[keep]


class ConsumedPixels:
    """gipuma's marks of source pixels already merged into a point, for the views not yet fused.

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


def iter_fused_points(views: Sequence[FusionView], neighbors: list[list[int]], cfg: FusionConfig,
                      progress: Callable | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Fuse reference views 0, 1, ... in turn, yielding world points [n,3] float32 and colours [n,3] uint8
    piece by piece. ``views`` is any sequence: a list in memory, or a store that loads views on demand
    (:class:`mvsformerpp.fusion.store.ViewStore`); the points are the same either way."""
    used = ConsumedPixels(views) if cfg.method == "gipuma" else None
    for r in range(len(views)):
        ref = views[r]
        srcs = [j for j in neighbors[r] if j != r][: cfg.num_src_views]
        H, W = ref.depth.shape
        good = (ref.depth > 0) & (ref.confidence > cfg.conf_threshold) & torch.isfinite(ref.depth)
        if used is not None:
            good &= ~used[r]
        idx_all = torch.nonzero(good.reshape(-1)).squeeze(1)
        chunk = max(1, cfg.chunk_pixels // max(1, len(srcs)))
        for start in range(0, len(idx_all), chunk):
            idx = idx_all[start:start + chunk]
            if not srcs:
                continue
            if cfg.method == "gipuma":
                xyz, rgb = _fuse_gipuma_ref(views, r, srcs, cfg, idx, used)
            else:
                kept, depth = _fuse_reprojection(ref, [views[j] for j in srcs], cfg, idx)
                u, v = _pixel_centres(H, W, kept)
                xyz = backproject(ref.K, ref.E, u, v, depth)
                rgb = ref.image.reshape(-1, 3)[kept].float()
            yield xyz.float().cpu().numpy(), rgb.round().clamp(0, 255).to(torch.uint8).cpu().numpy()
        if used is not None:
            used.finish(r)
        if progress is not None:
            progress(r)


def fuse_views(views: Sequence[FusionView], neighbors: list[list[int]], cfg: FusionConfig,
               progress: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fuse all views; returns world points [N,3] float32 and colours [N,3] uint8."""
    pieces = list(iter_fused_points(views, neighbors, cfg, progress))
    if not pieces:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    return np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces])
