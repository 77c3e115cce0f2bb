"""Scene views and their depth maps as fusion inputs (:class:`~mvsformerpp.fusion.core.FusionView`)."""

from __future__ import annotations

import numpy as np
import torch

from mvsformerpp.fusion.config import FusionConfig
from mvsformerpp.fusion.core import FusionView, fuse_views
from mvsformerpp.geometry.camera import scale_intrinsics
from mvsformerpp.io.scene import Scene, View


def make_view(view: View, depth: np.ndarray, confidence: np.ndarray | None, image: np.ndarray,
              device: str | torch.device = "cpu") -> FusionView:
    """A scene view's camera + its depth/confidence/image arrays -> :class:`FusionView` at depth resolution.

    K is scaled when the depth map is smaller or larger than the image (continuous-coordinate rule,
    :func:`~mvsformerpp.geometry.camera.scale_intrinsics`); the image is resized to the depth resolution for colours.
    """
    from PIL import Image

    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    K = scale_intrinsics(view.K, w / view.width, h / view.height)
    img = np.asarray(image)
    if img.shape[:2] != (h, w):
        img = np.asarray(Image.fromarray(img).resize((w, h), Image.BILINEAR))
    conf = np.ones_like(depth) if confidence is None else np.asarray(confidence, dtype=np.float32)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0).astype(np.float32)

    def t(a, dt=torch.float32):  # (arrays read from images can be read-only: torch needs writable)
        return torch.as_tensor(a if a.flags.writeable else a.copy(), dtype=dt, device=device)

    return FusionView(t(depth), t(conf), t(K), t(view.extrinsic), t(img[..., :3], torch.uint8))


def make_views(scene: Scene, depths: list[np.ndarray], confidences: list[np.ndarray] | None,
               images: list[np.ndarray], device: str | torch.device = "cpu") -> list[FusionView]:
    """:func:`make_view` for every view of the scene."""
    return [make_view(view, depths[i], None if confidences is None else confidences[i], images[i], device)
            for i, view in enumerate(scene.views)]


def fuse_depth_maps(scene: Scene, depths, confidences, images, config: FusionConfig | None = None,
                    device: str | torch.device = "cpu", progress=None) -> tuple[np.ndarray, np.ndarray]:
    """Fuse per-view depth maps (scene units, 0 = none) into world points [N,3] and colours [N,3] uint8."""
    config = config or FusionConfig()
    views = make_views(scene, depths, confidences, images, device)
    neighbors = [v.neighbors for v in scene.views]
    with torch.no_grad():
        return fuse_views(views, neighbors, config, progress)
