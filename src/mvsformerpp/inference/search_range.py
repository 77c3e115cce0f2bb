"""The depth range stage 1 searches: the camera's own, widened where its planes would be too close to tell apart.

Stage 1 spreads its planes evenly in inverse depth over the view's depth range, and it tells them apart
only by where they project in the source views. When the range is tight for the cameras' baselines (a
sparse-point range of a flat scene, video frames close together, a range from a depth sensor), two
neighbouring planes move the image by a few hundredths of a stage-1 pixel: the planes are
indistinguishable, stage 1 falls back on what it learned about where depths usually lie in a range, and
the finer stages, whose windows are a few of stage 1's steps wide, cannot undo it. Measured with the
shipped weights on a textured plane of exact depth (``bench/plane_check.py`` and the model card, "Depth
ranges too tight for the baseline"): a reference and one source, 1.6 % of the pixels within 1 % of the depth
at 0.03 stage-1 pixels per plane, 78 % at 0.11.

:func:`search_range` measures that shift, :func:`stage1_shift`, summed over the source views (each adds
evidence to the cost volume) as the median over a grid of reference pixels lifted to the middle of the
range, and widens the range about its middle in inverse depth until the shift reaches ``min_shift``
(never narrowing it). A range the cameras already resolve is left exactly as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvsformerpp.geometry.camera import plane_shift

MAX_FACTOR = 64.0
"""The most a range is widened (in inverse-depth span): beyond it the baseline is too short to help."""
FAR_FLOOR = 0.05
"""A widened range's far end stays at or nearer than 1 / (this x the original far end's inverse depth)."""


@dataclass(frozen=True)
class SearchRange:
    """What :func:`search_range` decided for one reference view."""

    depth_min: float
    depth_max: float
    shift: float
    """Stage 1's shift per plane in the given range (stage-1 pixels, summed over the sources)."""
    factor: float
    """How much the inverse-depth span was widened (1: the range as given)."""


def stage1_shift(K_ref: np.ndarray, E_ref: np.ndarray, sources: list[tuple[np.ndarray, np.ndarray]],
                 depth_min: float, depth_max: float, width: int, height: int, planes: int = 32,
                 stage_scale: float = 1 / 8, grid: int = 16) -> float:
    """Image shift between two neighbouring stage-1 planes, in stage-1 pixels, summed over ``sources``.

    ``K_ref``/``E_ref`` and each source's ``(K, E)``: intrinsics at the working resolution and 4x4
    world-to-camera matrices; ``width`` x ``height``: the working image. Per source, the median over a
    ``grid`` x ``grid`` lattice of reference pixels, lifted to the two planes nearest the range's middle (in
    inverse depth), of the distance between their projections, over the pixels whose projections both lie
    in front of the source and inside its image of the same size (a source that sees none adds nothing).
    """
    xs, ys = np.meshgrid((np.arange(grid) + 0.5) * width / grid, (np.arange(grid) + 0.5) * height / grid)
    pixels = np.stack([xs.ravel(), ys.ravel()])
    middle = 0.5 * (1.0 / depth_min + 1.0 / depth_max)
    step = (1.0 / depth_min - 1.0 / depth_max) / (planes - 1)
    total = 0.0
    for K, E in sources:
        distance, uv, front = plane_shift(K_ref, E_ref, K, E, pixels, middle - step / 2, middle + step / 2)
        inside = front & np.all((uv >= 0) & (uv < np.array([[width], [height]])), axis=0)
        if inside.any():
            total += float(np.median(distance[inside])) * stage_scale
    return total


def widen_inverse_range(depth_min: float, depth_max: float, factor: float) -> tuple[float, float]:
    """``(depth_min, depth_max)`` with its inverse-depth span times ``factor`` about the span's middle; where
    the far end would pass :data:`FAR_FLOOR` of its inverse depth, the excess goes to the near side."""
    near, far = 1.0 / depth_min, 1.0 / depth_max
    middle, half = 0.5 * (near + far), 0.5 * (near - far) * factor
    new_far, new_near = middle - half, middle + half
    floor = FAR_FLOOR * far
    if new_far < floor:
        new_near += floor - new_far
        new_far = floor
    return 1.0 / new_near, 1.0 / new_far


def search_range(K_ref: np.ndarray, E_ref: np.ndarray, sources: list[tuple[np.ndarray, np.ndarray]],
                 depth_min: float, depth_max: float, width: int, height: int, min_shift: float,
                 planes: int = 32) -> SearchRange:
    """The range stage 1 should search: the given one unless its shift per plane (:func:`stage1_shift`) is
    below ``min_shift`` stage-1 pixels, else widened (:func:`widen_inverse_range`) by ``min_shift / shift``
    (at most :data:`MAX_FACTOR`). ``min_shift`` 0 keeps every range. Sources that see none of the reference
    leave the range as it is (no range would give them parallax)."""
    if min_shift <= 0:
        return SearchRange(depth_min, depth_max, float("nan"), 1.0)
    shift = stage1_shift(K_ref, E_ref, sources, depth_min, depth_max, width, height, planes)
    if shift <= 0 or shift >= min_shift:
        return SearchRange(depth_min, depth_max, shift, 1.0)
    factor = min(MAX_FACTOR, min_shift / shift)
    return SearchRange(*widen_inverse_range(depth_min, depth_max, factor), shift, factor)
