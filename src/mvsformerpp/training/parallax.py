"""Image shift per depth hypothesis: what each cascade stage must resolve, for training views and real photos.

A stage tells its hypotheses apart only by where they project in the source views. For a reference pixel
of true depth d, stage s's neighbouring planes sit ``step_s`` apart in inverse depth around 1/d, and
their projections into a source view lie ``shift_s`` pixels apart, counted at that stage's own
resolution (1/8, 1/4, 1/2, 1 of the input). The steps follow the network's hypothesis rule
(:mod:`mvsformerpp.models.hypotheses`): stage 1 spreads ``D_1`` planes over the inverse-depth range,
stage s > 1 ``D_s`` planes over ``2 ratio_s`` of the previous stage's step.

A view set's shift at a stage is the median over its source views of each view's median over the
reference's valid pixels. A training recipe whose views have far smaller shifts than the photos the
network is used on never trains its fine stages; :func:`recipe_shifts` samples a recipe's views and
:func:`check_parallax` refuses a recipe whose views fall outside the range it declares
(``parallax_range``). Shifts only help where the views see the same points: a view set's overlap is the
share of the reference's valid pixels whose true point lies inside a source image, in front of it, as the
mean over its source views (:func:`view_overlap`); ``min_overlap`` declares the least median overlap a
recipe accepts.

``python -m mvsformerpp.training.parallax RECIPE_OR_CONFIG [--samples N] [--set key=value ...]`` prints the
distribution for a recipe; ``--scene DIR`` for an MVSNet-layout folder with depth maps.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from mvsformerpp.data.base import SampleKey, ViewData
from mvsformerpp.errors import InputError
from mvsformerpp.geometry.camera import depth_to_points, plane_shift, project
from mvsformerpp.io.mvsnet import read_cam
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.models.inputs import STAGE_SCALES
from mvsformerpp.models.presets import get_config
from mvsformerpp.training.config import load_config, parse_overrides
from mvsformerpp.training.datasets import build_datasets

SCALES = tuple(STAGE_SCALES.values())
PERCENTILES = (10, 50, 90)


def plane_steps(num_hypotheses, ratios) -> np.ndarray:
    """Each stage's inverse-depth step as a fraction of the range's inverse span (1/dmin - 1/dmax)."""
    steps = [1.0 / (num_hypotheses[0] - 1)]
    for d, r in zip(num_hypotheses[1:], ratios[1:]):
        steps.append(2.0 * r * steps[-1] / (d - 1))
    return np.asarray(steps)


def _default_steps() -> np.ndarray:
    cfg = get_config("lite")
    return plane_steps(cfg.num_hypotheses, cfg.hypothesis_ratio)


def view_shifts(K_ref, E_ref, K_src, E_src, depth: np.ndarray, depth_min: float, depth_max: float,
                steps: np.ndarray | None = None, max_points: int = 4000) -> np.ndarray:
    """Median shift per plane (pixels at each stage's resolution) of one source view, one value per stage.

    ``depth``: the reference's true depth (0 = unknown); cameras as 3x3 intrinsics and 4x4 world-to-camera.
    NaN where no valid pixel projects in front of the source camera.
    """
    steps = _default_steps() if steps is None else np.asarray(steps)
    ys, xs = np.nonzero(depth > 0)
    if len(ys) == 0:
        return np.full(len(steps), np.nan)
    if len(ys) > max_points:
        pick = np.linspace(0, len(ys) - 1, max_points).astype(np.int64)
        ys, xs = ys[pick], xs[pick]
    inv = 1.0 / depth[ys, xs].astype(np.float64)
    pixels = np.stack([xs + 0.5, ys + 0.5]).astype(np.float64)  # pixel centres
    span = 1.0 / depth_min - 1.0 / depth_max
    out = []
    for step, scale in zip(steps, SCALES):
        half = 0.5 * step * span
        distance, _, front = plane_shift(K_ref, E_ref, K_src, E_src, pixels, np.maximum(inv - half, 1e-3 * inv),
                                         inv + half)
        out.append(float(np.median(distance[front])) * scale if front.any() else np.nan)
    return np.asarray(out)


def view_overlap(K_ref, E_ref, K_src, E_src, depth: np.ndarray, src_size: tuple[int, int]) -> float:
    """Share of the reference's valid pixels (``depth`` > 0) whose true point lies inside the source image of
    ``src_size`` = (height, width) pixels and in front of it (occlusion is not tested). NaN without valid pixels."""

    valid = depth > 0
    if not valid.any():
        return float("nan")
    t = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    points = depth_to_points(t(depth), t(K_ref), t(E_ref))[torch.from_numpy(valid)]
    u, v, z = project(t(K_src), t(E_src), points)
    h, w = src_size
    inside = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return float(inside.double().mean())


def _supervised(view) -> np.ndarray:
    return view.depth * (view.mask if view.mask is not None else 1)


def viewset_shifts(views, depth_min: float, depth_max: float, steps: np.ndarray | None = None) -> np.ndarray:
    """A view set's shift per stage: the median over its source views (``views[0]`` the reference with depth)."""
    ref = views[0]
    per_view = np.stack([view_shifts(ref.K, ref.E, v.K, v.E, _supervised(ref), depth_min, depth_max, steps)
                         for v in views[1:]])
    return np.nanmedian(per_view, axis=0)


def viewset_overlap(views) -> float:
    """A view set's overlap: the mean over its source views of :func:`view_overlap` (``views[0]`` the
    reference with depth; each source's image gives its size)."""
    ref = views[0]
    return float(np.nanmean([view_overlap(ref.K, ref.E, v.K, v.E, _supervised(ref), v.image.shape[:2])
                             for v in views[1:]]))


def recipe_shifts(config, samples: int = 48) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(shifts [samples, 4], focal lengths [samples], overlaps [samples]) of a training config's views as
    training feeds them: evenly spaced samples of the training set, each at the next of the recipe's
    resolutions."""

    cfg = get_config(config.preset)
    steps = plane_steps(cfg.num_hypotheses, cfg.hypothesis_ratio)
    train, _ = build_datasets(config)
    train = getattr(train, "datasets", [train])[0]  # a mix (real photos beside synthetic scenes): its first set
    sizes = list(config.resolutions) or [(config.height, config.width)]
    picks = np.linspace(0, len(train) - 1, samples).astype(np.int64)
    shifts, focals, overlaps = [], [], []
    for k, index in enumerate(picks):
        h, w = sizes[k % len(sizes)]
        vs = train.views(SampleKey(int(index), int(h), int(w)))
        shifts.append(viewset_shifts(vs.views, vs.depth_min, vs.depth_max, steps))
        focals.append(float(vs.views[0].K[0, 0]))
        overlaps.append(viewset_overlap(vs.views))
    return np.stack(shifts), np.asarray(focals), np.asarray(overlaps)


def scene_shifts(folder, max_size: int | None = None,
                 steps: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """(shifts [4], median focal, median overlap) of an MVSNet-layout folder whose cams come with
    ``depth_map_NNNN.pfm`` ground truth of the cams' resolution: every view with depth is a reference, all
    others its sources (a source without a depth map has no known image size: no overlap).
    ``max_size``: the working size (longest side) the photos run at (default: the depth maps' size)."""

    folder = Path(folder)
    cams = sorted(folder.glob("*_cam.txt")) or sorted((folder / "cams").glob("*_cam.txt"))
    if len(cams) < 2:
        raise InputError(f"{folder}: needs at least two cam files (NNNNNNNN_cam.txt)")
    views, ranges, scales = [], [], []
    for i, path in enumerate(cams):
        cam = read_cam(path)
        found = sorted(folder.glob(f"depth_map_{i:04d}.pfm")) + sorted(folder.glob(f"depths/depth_map_{i:04d}.pfm"))
        depth = read_pfm(found[0]) if found else None
        size = depth.shape if depth is not None else (0, 0)  # the image the cam's K belongs to
        views.append(ViewData(np.broadcast_to(np.zeros(1, np.uint8), (*size, 3)), np.asarray(cam.K, np.float64),
                              np.asarray(cam.extrinsic, np.float64), depth))
        ranges.append((cam.depth_min, cam.depth_max))
        if depth is not None:
            scales.append(1.0 if max_size is None else max_size / max(depth.shape))
    out, overlaps = [], []
    for r, ref in enumerate(views):
        if ref.depth is None or ranges[r][0] is None:
            continue
        others = [v for j, v in enumerate(views) if j != r]
        out.append(viewset_shifts([ref] + others, *ranges[r], steps) * scales[len(out)])
        sized = [v for v in others if v.image.shape[0] > 0]
        overlaps.append(viewset_overlap([ref] + sized) if sized else float("nan"))
    if not out:
        raise InputError(f"{folder}: no depth_map_NNNN.pfm with a depth range in its cam file; the shifts need "
                         "true depth")
    focal = float(np.median([v.K[0, 0] for v in views]) * np.median(scales))
    return np.nanmedian(np.stack(out), axis=0), focal, float(np.nanmedian(overlaps))


def check_parallax(config, samples: int | None = None) -> np.ndarray | None:
    """Refuse a config whose training views fall outside its declared ``parallax_range`` (stage-4 pixels):
    the 10th and 90th percentiles of the sampled views' stage-4 shift must lie inside it; and, where it
    declares ``min_overlap``, views whose median overlap is below it. Returns the sampled shifts (None when
    the config declares neither)."""
    if config.parallax_range is None and config.min_overlap is None:
        return None
    shifts, _, overlaps = recipe_shifts(config, samples or config.parallax_samples)
    fix = ("change the views (synthetic_options: sensor_width, resolutions) or the declaration "
           "(python -m mvsformerpp.training.parallax RECIPE prints the distribution)")
    if config.parallax_range is not None:
        lo, hi = config.parallax_range
        p10, p90 = np.nanpercentile(shifts[:, 3], [10, 90])
        if p10 < lo or p90 > hi:
            raise InputError(
                f"the recipe's training views have stage-4 shifts of {p10:.2f}-{p90:.2f} px per plane (10th-90th "
                f"percentile of {len(shifts)} samples), outside its declared parallax_range [{lo:g}, {hi:g}]; {fix}")
    if config.min_overlap is not None:
        median = float(np.nanmedian(overlaps))
        if not median >= config.min_overlap:
            raise InputError(
                f"the recipe's source views see a median {100 * median:.0f} % of the reference's pixels "
                f"({len(overlaps)} samples; 10th percentile {100 * np.nanpercentile(overlaps, 10):.0f} %), below its "
                f"declared min_overlap {config.min_overlap:g}; {fix}")
    return shifts


def format_table(rows: dict[str, tuple]) -> str:
    """Rows of (shifts [N, 4] or [4], focal(s), overlap(s)) as a text table: percentiles for sampled rows."""
    n = max([34, *(len(name) for name in rows)])
    lines = [f"{'':{n}s} {'stage 1':>16s} {'stage 2':>16s} {'stage 3':>16s} {'stage 4':>16s} {'focal (px)':>16s}"
             f" {'overlap (%)':>16s}",
             f"{'(px per plane, own resolution)':{n}s}" + "".join(f"{'p10/p50/p90':>17s}" for _ in range(6))]
    for name, (shifts, focal, overlap) in rows.items():
        shifts = np.atleast_2d(shifts)
        focal, overlap = np.atleast_1d(focal), 100 * np.atleast_1d(overlap)
        if len(shifts) == 1:
            cells = [f"{v:16.2f}" for v in shifts[0]] + [f"{np.median(focal):16.0f}", f"{overlap[0]:16.0f}"]
        else:
            cells = ["{:>16s}".format("/".join(f"{v:.2f}" for v in np.nanpercentile(shifts[:, k], PERCENTILES)))
                     for k in range(shifts.shape[1])]
            cells += ["{:>16s}".format("/".join(f"{v:.0f}" for v in np.nanpercentile(x, PERCENTILES)))
                      for x in (focal, overlap)]
        lines.append(f"{name:{n}s} " + " ".join(cells))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m mvsformerpp.training.parallax", description=__doc__.split("\n\n")[0])
    p.add_argument("config", nargs="*", metavar="RECIPE_OR_CONFIG", help="recipes or YAML configs to sample")
    p.add_argument("--samples", type=int, default=48, help="training samples per recipe (default 48)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    p.add_argument("--scene", action="append", default=[], metavar="DIR",
                   help="an MVSNet-layout folder with depth_map_NNNN.pfm ground truth (a real-photo row)")
    p.add_argument("--max-size", type=int, help="--scene rows: the working size (longest side, pixels)")
    args = p.parse_args(argv)
    if args.samples < 1:
        p.error("--samples must be at least 1")
    rows = {}
    try:
        for spec in args.config:
            config = load_config(spec, parse_overrides(args.set))
            rows[spec] = recipe_shifts(config, args.samples)
        for folder in args.scene:
            rows[folder] = scene_shifts(folder, max_size=args.max_size)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
