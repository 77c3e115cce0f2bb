"""A scene at a glance: what ``mvsformerpp info`` prints, as plain data."""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from mvsformerpp.io.scene import Scene


def _stats(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    arr = np.asarray(values, dtype=np.float64)
    return {"min": float(arr.min()), "median": float(np.median(arr)), "max": float(arr.max())}


def summarize_scene(scene: Scene, layout: str | None = None, per_view: bool = False) -> dict[str, Any]:
    """JSON-ready summary: layout, view count, resolutions, depth ranges, neighbour counts, GT depth count.

    ``resolutions`` maps ``"WxH"`` to the number of views of that size (most common first);
    ``depth_min``/``depth_max`` give min/median/max over the views that have a range. With
    ``per_view``, ``views`` lists every view (name, image, size, focal lengths, depth range, neighbours).
    """
    views = scene.views
    res = Counter(f"{v.width}x{v.height}" for v in views)
    with_range = [v for v in views if v.depth_min is not None and v.depth_max is not None]
    nbrs = [len(v.neighbors) for v in views]
    return {
        "path": str(scene.root) if scene.root is not None else None,
        "layout": layout or scene.source_format,
        "num_views": len(views),
        "resolutions": dict(res.most_common()),
        "views_with_depth_range": len(with_range),
        "depth_min": _stats([v.depth_min for v in with_range]),
        "depth_max": _stats([v.depth_max for v in with_range]),
        "neighbors": _stats([float(n) for n in nbrs]),
        "views_without_neighbors": sum(n == 0 for n in nbrs),
        "views_with_gt_depth": sum(v.depth_gt_path is not None for v in views),
        "views_with_mask": sum(v.mask_path is not None for v in views),
    } | ({"views": [_view_entry(v) for v in views]} if per_view else {})


def _view_entry(v) -> dict[str, Any]:
    return {
        "name": v.name,
        "image": str(v.image_path),
        "size": [v.width, v.height],
        "focal": [float(v.K[0, 0]), float(v.K[1, 1])],
        "depth_range": None if v.depth_min is None else [float(v.depth_min), float(v.depth_max)],
        "neighbors": list(v.neighbors),
        "depth_gt": str(v.depth_gt_path) if v.depth_gt_path is not None else None,
    }


def format_summary(s: dict[str, Any]) -> str:
    """Human-readable text of :func:`summarize_scene`'s dict."""

    def trio(st: dict[str, float] | None) -> str:
        return "-" if st is None else f"{st['min']:.6g} / {st['median']:.6g} / {st['max']:.6g}"

    lines = [
        f"scene:        {s['path']}",
        f"layout:       {s['layout']}",
        f"views:        {s['num_views']}",
        "resolutions:  " + ", ".join(f"{k} ({n} view{'s' if n != 1 else ''})" for k, n in s["resolutions"].items()),
        f"depth range:  {s['views_with_depth_range']} of {s['num_views']} views have one "
        "(min / median / max over views)",
        f"  near:       {trio(s['depth_min'])}",
        f"  far:        {trio(s['depth_max'])}",
        f"neighbours:   {trio(s['neighbors'])} per view (min / median / max)"
        + (f"; {s['views_without_neighbors']} view(s) without any" if s["views_without_neighbors"] else ""),
        f"ground truth: {s['views_with_gt_depth']} depth map(s), {s['views_with_mask']} mask(s)",
    ]
    if s.get("depth_lines"):
        lines.insert(7, "depth lines:  " + ", ".join(f"{n} read as {form}" for form, n in s["depth_lines"].items()))
    par = s.get("stage1_parallax")
    if par:
        widened = par["widened_views"]
        shift = " / ".join(f"{par['shift'][k]:.3g}" for k in ("min", "median", "max"))
        lines.append(f"stage 1:      {shift} px of image shift per depth plane (min / median / max over "
                     f"{par['views']} views; reconstruct's defaults here: long side {par['long_side']} px, "
                     f"{par['views_per_depth_map']} views per depth map)")
        if widened:
            names = ", ".join(str(i) for i in widened[:8]) + (" ..." if len(widened) > 8 else "")
            lines.append(f"  tight:      {len(widened)} views below {par['min_parallax']:g} px ({names}): reconstruct "
                         "widens their depth range (--min-parallax)")
    if "views" in s:
        lines.append("")
        lines.append(f"{'#':>4}  {'name':<24} {'size':>11}  {'focal':>9}  {'depth range':>23}  neighbours")
        for i, v in enumerate(s["views"]):
            rng = "-" if v["depth_range"] is None else f"{v['depth_range'][0]:.5g} .. {v['depth_range'][1]:.5g}"
            size = f"{v['size'][0]}x{v['size'][1]}"
            nb = " ".join(str(j) for j in v["neighbors"])
            lines.append(f"{i:>4}  {v['name'][:24]:<24} {size:>11}  {v['focal'][0]:>9.6g}  {rng:>23}  {nb}")
    return "\n".join(lines)
