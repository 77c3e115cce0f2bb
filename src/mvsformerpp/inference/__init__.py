"""Inference: working resolution, per-image feature cache, and the scene-to-tensor adapter."""

from mvsformerpp.inference.feature_cache import FeatureCache, tree_cat, tree_nbytes
from mvsformerpp.inference.resolution import ViewResize, choose_long_side, plan_views
from mvsformerpp.inference.runner import SceneInference, ViewResult, select_sources, stage_projections

__all__ = [
    "FeatureCache", "SceneInference", "ViewResize", "ViewResult", "choose_long_side", "plan_views",
    "select_sources", "stage_projections", "tree_cat", "tree_nbytes",
]
