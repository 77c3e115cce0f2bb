"""Adapt a :class:`~mvsformerpp.io.scene.Scene` to the network's tensors and back, view by view.

For each reference view: pick ``num_views - 1`` source views from its neighbours (padded by
repeating the first source when there are too few, as the reference test loader does), resize and
pad every image to the shared canvas (:mod:`.resolution`), build the per-stage projection matrices
(slot 0: world-to-camera 4x4; slot 1: K at 1/8, 1/4, 1/2, 1 of the canvas resolution, as the
official loaders build them), run the model, and crop/resize the depth and the 4-stage mean
photometric confidence back to the original image size.

The per-image encoder features come from a :class:`.feature_cache.FeatureCache`, so each image is
encoded once per scene (while it stays in the cache) instead of once per reference view.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from mvsformerpp.inference.feature_cache import FeatureCache
from mvsformerpp.inference.resolution import ViewResize
from mvsformerpp.inference.schedule import cache_friendly_order, simulate_cache
from mvsformerpp.inference.search_range import SearchRange, search_range
from mvsformerpp.io.scene import Scene
from mvsformerpp.models import prepared
from mvsformerpp.models.inputs import normalize, stage_projections
from mvsformerpp.utils.lru import tree_nbytes
from mvsformerpp.utils.precision import autocast, check_precision


@dataclass
class ViewResult:
    """Outputs of one reference view at its original resolution."""

    depth: np.ndarray  # [H, W] float32, scene units
    confidence: np.ndarray  # [H, W] float32 in [0, 1]
    source_views: list[int]
    seconds: float
    search_range: tuple[float, float] | None = None
    """The depth range stage 1 searched (:mod:`.search_range`)."""
    range_factor: float = 1.0
    """How much that range's inverse-depth span was widened over the view's own (1: not)."""


def select_sources(scene: Scene, ref: int, num_views: int) -> list[int]:
    """``num_views - 1`` source view indices for ``ref`` (best neighbours first, padded by repetition)."""
    nbrs = [j for j in scene.views[ref].neighbors if j != ref]
    if not nbrs:
        raise ValueError(f"view {ref} has no neighbours")
    need = num_views - 1
    srcs = nbrs[:need]
    return srcs + [srcs[0]] * (need - len(srcs))


def view_cameras(scene: Scene, plans: list[ViewResize], ref: int, num_views: int):
    """``(K_ref, E_ref, [(K, E) per source], width, height)`` of reference view ``ref``'s view set at the working
    resolution (``plans``): what :mod:`.search_range` measures stage 1's shift per plane from."""
    ids = [ref] + select_sources(scene, ref, num_views)
    cams = [(plans[i].scale_intrinsics(scene.views[i].K), scene.views[i].extrinsic) for i in ids]
    return (*cams[0], cams[1:], plans[ref].resized_width, plans[ref].resized_height)


def view_search_range(scene: Scene, plans: list[ViewResize], ref: int, num_views: int, min_parallax: float,
                      planes: int = 32) -> SearchRange:
    """The depth range stage 1 searches for reference view ``ref`` (:mod:`.search_range`), from the cameras of
    its view set alone."""
    K, E, sources, width, height = view_cameras(scene, plans, ref, num_views)
    view = scene.views[ref]
    return search_range(K, E, sources, view.depth_min, view.depth_max, width, height, min_parallax, planes)


class SceneInference:
    """Run a depth network over the views of a scene with a per-image feature cache.

    ``model`` follows the MVSFormer++ interface: ``encode_images(imgs [N,3,H,W])`` returns per-image
    features and ``forward(imgs [1,V,3,H,W], proj_matrices, depth_values [1,D], temperatures,
    image_features=..., release_features=True)`` returns ``depth`` and ``photometric_confidence``
    ``[1,H,W]`` (the features passed are a concatenated copy made for that call, which the network may
    empty once it no longer needs them).
    The runner prepares ``model`` for inference (:mod:`mvsformerpp.models.prepared`).
    ``load_image(i)`` returns view ``i``'s uint8 ``[H,W,3]`` photo at its original size.
    ``cache_bytes=0`` disables the cache: ``forward`` then encodes every image of every view set.
    ``attention_bf16``: the network's stage-1 transformer attention in bf16 inside an fp32 forward
    (``set_attention_precision``, where the network has it; ``reconstruct --precision auto`` decides).
    ``min_parallax``: stage 1 searches each view's depth range widened until neighbouring planes move the
    source images by this many stage-1 pixels in all (:mod:`.search_range`; 0: the ranges as given).
    """

    def __init__(self, model: torch.nn.Module, scene: Scene, plans: list[ViewResize], load_image,
                 num_views: int, num_depth: int = 192, temperatures: tuple[float, ...] = (5.0, 5.0, 5.0, 1.0),
                 device: str | torch.device = "cpu", precision: str = "fp32", cache_bytes: int = 2 << 30,
                 output_resolution: str = "original", attention_bf16: bool = False, min_parallax: float = 0.0):
        check_precision(precision)
        prepare = getattr(model, "prepare_for_inference", None)  # (a network run by another runtime has its own)
        self.model = prepare() if callable(prepare) else prepared.prepare(model)  # eval mode, inference forms built
        if callable(getattr(model, "set_attention_precision", None)):
            model.set_attention_precision("bf16" if attention_bf16 else "fp32")
        self.scene = scene
        self.plans = plans
        self.load_image = load_image
        self.num_views = int(num_views)
        self.num_depth = int(num_depth)
        self.temperatures = list(temperatures)
        self.device = torch.device(device)
        self.precision = precision
        if output_resolution not in ("original", "working"):
            raise ValueError(f"output_resolution must be 'original' or 'working', got {output_resolution!r}")
        self.output_resolution = output_resolution
        self.min_parallax = float(min_parallax)
        config = getattr(model, "config", None)
        self.stage1_planes = int(config.num_hypotheses[0]) if hasattr(config, "num_hypotheses") else 32
        # A network without a separate per-image encoder runs without the cache.
        self.use_cache = cache_bytes > 0 and callable(getattr(model, "encode_images", None))
        self.cache = FeatureCache(self._encode, cache_bytes)

    def canvas_image(self, i: int) -> torch.Tensor:
        """View ``i`` resized, padded and normalised: ``[3, Hc, Wc]`` on the device."""
        return normalize(self.plans[i].image_to_canvas(self.load_image(i))).to(self.device)

    @torch.no_grad()
    def _encode(self, i: int) -> Any:
        with autocast(self.device, self.precision):
            return self.model.encode_images(self.canvas_image(i)[None])

    def view_set(self, ref: int) -> list[int]:
        """The images reference view ``ref`` needs: itself and its source views."""
        return [ref] + select_sources(self.scene, ref, self.num_views)

    def schedule(self, todo: list[int]) -> dict:
        """A cache-friendly order of the reference views ``todo`` (:mod:`.schedule`) and what it predicts.

        The cache capacity in images comes from the size of one image's features: the first view's
        reference image is encoded here (and cached, so its own view then hits). Returns ``order``,
        ``capacity_images`` and the simulated ``predicted`` / ``predicted_index_order`` hits and misses.
        """

        if not todo or not self.use_cache:
            return {"order": list(todo), "capacity_images": 0}
        capacity = self.cache.max_bytes // max(1, tree_nbytes(self.cache.get(todo[0])))
        sets = {r: self.view_set(r) for r in todo}
        order = cache_friendly_order(todo, sets, capacity)
        return {"order": order, "capacity_images": int(capacity), "predicted": simulate_cache(order, sets, capacity),
                "predicted_index_order": simulate_cache(sorted(todo), sets, capacity)}

    @torch.no_grad()
    def infer(self, ref: int) -> ViewResult:
        """Depth and confidence of reference view ``ref`` at its original resolution (or the working one)."""
        import time

        t0 = time.perf_counter()
        ids = self.view_set(ref)
        srcs = ids[1:]
        views = [self.scene.views[i] for i in ids]
        plan = self.plans[ref]
        feats = self.cache.get_many(ids) if self.use_cache else None
        if feats is None:
            imgs = torch.stack([self.canvas_image(i) for i in ids])[None]  # [1,V,3,Hc,Wc]
        else:  # the network reads only the images' shape from here: no photo is loaded again
            imgs = torch.zeros((), device=self.device).expand(1, len(ids), 3, plan.canvas_height, plan.canvas_width)
        extr = np.stack([v.extrinsic for v in views])
        intr = np.stack([self.plans[i].scale_intrinsics(v.K) for i, v in zip(ids, views)])
        projs = {k: v.to(self.device) for k, v in stage_projections(extr, intr).items()}
        searched = view_search_range(self.scene, self.plans, ref, self.num_views, self.min_parallax, self.stage1_planes)
        depth_values = torch.linspace(searched.depth_min, searched.depth_max, self.num_depth,
                                      dtype=torch.float32, device=self.device)[None]
        with autocast(self.device, self.precision):
            out = self.model(imgs, projs, depth_values, self.temperatures, image_features=feats,
                             release_features=feats is not None)
        if self.output_resolution == "working":
            depth = plan.canvas_to_working(out["depth"][0].float())
            conf = plan.canvas_to_working(out["photometric_confidence"][0].float())
        else:
            depth, conf = plan.depth_to_original(out["depth"][0], out["photometric_confidence"][0])
        depth = torch.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0).clamp_(min=0.0)
        conf = torch.nan_to_num(conf, nan=0.0).clamp_(0.0, 1.0)
        return ViewResult(depth=depth.cpu().numpy().astype(np.float32),
                          confidence=conf.cpu().numpy().astype(np.float32),
                          source_views=srcs, seconds=time.perf_counter() - t0,
                          search_range=(searched.depth_min, searched.depth_max), range_factor=searched.factor)
