"""Depth-map fusion into a coloured point cloud: ``normal``, ``dynamic`` (DPCD) and ``gipuma`` filters
(:data:`~mvsformerpp.fusion.config.METHODS`).

The configuration is imported eagerly (the command line builds its flags from it); the fusion code, which
needs torch, on first use of its names.
"""

from __future__ import annotations

from mvsformerpp.fusion.choice import FusionChoice, choose_fusion
from mvsformerpp.fusion.config import METHODS, PRESETS, FusionConfig, FusionMethod, get_config
from mvsformerpp.utils.lazy import lazy_names

__all__ = ["METHODS", "FusionChoice", "FusionConfig", "FusionMethod", "FusionView", "PRESETS", "choose_fusion",
           "fuse_depth_maps", "fuse_views", "get_config", "iter_fused_points", "make_view", "make_views"]

_LAZY = {"FusionView": "core", "fuse_views": "core", "iter_fused_points": "core", "make_view": "views",
         "make_views": "views", "fuse_depth_maps": "views"}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
