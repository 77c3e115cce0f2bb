"""Depth-map fusion in PyTorch: the views, the primitives the methods share, and the loop over reference views.

Each method (:data:`~mvsformerpp.fusion.config.METHODS`: the reference's ``normal``, ``dynamic`` and
``gipuma`` filters) is a :class:`FusionKernel` in a module of its own; :func:`iter_fused_points` walks the
reference views, picks each one's confident pixels and hands them to the kernel in chunks.

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

from mvsformerpp.errors import InputError
from mvsformerpp.fusion.config import FusionConfig, get_method
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


def pixel_centres(H: int, W: int, idx: torch.Tensor):
    """Continuous coordinates (u, v) of the centres of the flat pixel indices ``idx`` of an [H, W] map."""
    return (idx % W).to(torch.float32) + 0.5, (idx // W).to(torch.float32) + 0.5


def reprojection_errors(ref: FusionView, srcs: list[FusionView], src_depths, u, v, d):
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


def confident_depth(view: FusionView, cfg: FusionConfig) -> torch.Tensor:
    """The view's depth with the pixels at or below the confidence threshold set to 0 (no estimate):
    what ``normal`` and ``gipuma`` see of a source view."""
    return torch.where(view.confidence > cfg.conf_threshold, view.depth, torch.zeros_like(view.depth))


class FusionKernel:
    """One fusion method over a sequence of views: which reference pixels it may still use and the points
    it makes of them. Subclasses implement :meth:`fuse`; the others have defaults for methods without state."""

    def __init__(self, views: Sequence[FusionView], cfg: FusionConfig):
        self.views, self.cfg = views, cfg

    def taken(self, r: int) -> torch.Tensor | None:
        """[H, W] bool: pixels of view r already merged into a point (None: none are)."""
        return None

    def fuse(self, r: int, sources: list[int], idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points [n, 3] and colours [n, 3] (float, 0..255) of the reference pixels ``idx`` (flat
        indices into view r's map) that the ``sources`` confirm."""
        raise NotImplementedError

    def finish(self, r: int) -> None:
        """Reference view r is fused."""


class ReprojectionKernel(FusionKernel):
    """A method that projects each reference depth into the source views and back
    (:func:`reprojection_errors`), keeps the pixels :meth:`consistent` says, and averages the depths of
    the consistent sources with the reference's."""

    filter_sources = False
    """Sources' depths at or below the confidence threshold are dropped before the check."""

    def consistent(self, err: torch.Tensor, dr: torch.Tensor, d: torch.Tensor,
                   valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(keep [n], consistent [S, n]) from the reprojection errors ``err`` [S, n], the reprojected depths
        ``dr`` [S, n], the reference depths ``d`` [n] and the validity ``valid`` [S, n]: the pixels kept and
        the source depths averaged into each."""
        raise NotImplementedError

    def kept(self, r: int, sources: list[int], idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(flat indices [n] of the reference pixels ``idx`` of view r that the ``sources`` confirm, their fused
        depths [n]): the reference depth averaged with the consistent sources' reprojected depths."""
        ref, srcs = self.views[r], [self.views[j] for j in sources]
        u, v = pixel_centres(*ref.depth.shape, idx)
        d = ref.depth.reshape(-1)[idx]
        src_depths = [confident_depth(s, self.cfg) if self.filter_sources else s.depth for s in srcs]
        err, dr, valid = reprojection_errors(ref, srcs, src_depths, u, v, d)
        keep, consistent = self.consistent(err, dr, d, valid)
        fused = (d + (dr * consistent).sum(0)) / (1 + consistent.sum(0))
        return idx[keep], fused[keep]

    def fuse(self, r: int, sources: list[int], idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        ref = self.views[r]
        kept, depth = self.kept(r, sources, idx)
        u, v = pixel_centres(*ref.depth.shape, kept)
        return backproject(ref.K, ref.E, u, v, depth), ref.image.reshape(-1, 3)[kept].float()


def consistent_pixels(ref: FusionView, srcs: list[FusionView], cfg: FusionConfig) -> torch.Tensor:
    """Flat indices of the reference pixels with depth that the method of ``cfg`` (one that checks each pixel
    by reprojection, a :class:`ReprojectionKernel`: ``normal``, ``dynamic``) keeps against ``srcs``: what
    fusion would fuse (the teacher labels of ``tools/teacher_labels.py``)."""
    kernel = get_method(cfg.method).kernel()([ref, *srcs], cfg)
    if not isinstance(kernel, ReprojectionKernel):
        raise InputError(f"fusion method {cfg.method} does not check pixels by reprojection; use normal or dynamic")
    idx = torch.nonzero((ref.depth.reshape(-1) > 0) & (ref.confidence.reshape(-1) > cfg.conf_threshold)).squeeze(1)
    return kernel.kept(0, list(range(1, len(srcs) + 1)), idx)[0]


def iter_fused_points(views: Sequence[FusionView], neighbors: list[list[int]], cfg: FusionConfig,
                      progress: Callable | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Fuse reference views 0, 1, ... in turn, yielding world points [n,3] float32 and colours [n,3] uint8
    piece by piece. ``views`` is any sequence: a list in memory, or a store that loads views on demand
    (:class:`mvsformerpp.fusion.store.ViewStore`); the points are the same either way."""
    method = get_method(cfg.method)
    if not isinstance(cfg, type(method.defaults)):
        raise InputError(f"fusion method {method.name} takes {type(method.defaults).__name__} settings, got "
                         f"{type(cfg).__name__}")
    kernel = method.kernel()(views, cfg)
    for r in range(len(views)):
        ref = views[r]
        srcs = [j for j in neighbors[r] if j != r][: cfg.num_src_views]
        good = (ref.depth > 0) & (ref.confidence > cfg.conf_threshold) & torch.isfinite(ref.depth)
        taken = kernel.taken(r)
        if taken is not None:
            good &= ~taken
        idx_all = torch.nonzero(good.reshape(-1)).squeeze(1)
        chunk = max(1, cfg.chunk_pixels // max(1, len(srcs)))
        for start in range(0, len(idx_all), chunk):
            idx = idx_all[start:start + chunk]
            if not srcs:
                continue
            xyz, rgb = kernel.fuse(r, srcs, idx)
            yield xyz.float().cpu().numpy(), rgb.round().clamp(0, 255).to(torch.uint8).cpu().numpy()
        kernel.finish(r)
        if progress is not None:
            progress(r)


def fuse_views(views: Sequence[FusionView], neighbors: list[list[int]], cfg: FusionConfig,
               progress: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fuse all views; returns world points [N,3] float32 and colours [N,3] uint8."""
    pieces = list(iter_fused_points(views, neighbors, cfg, progress))
    if not pieces:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    return np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces])
