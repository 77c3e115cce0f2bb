"""How much a set of views lets each cascade stage tell its depth planes apart, with no network.

    python bench/plane_oracle.py [RECIPE ...] [--samples 48] [--dtu]

For every valid reference pixel, a stage's window of planes (its plane count and inverse-depth spacing,
as the network's hypothesis rule has them) is placed around the true depth, the truth at a random place
inside it (one draw per sample and stage, so neighbouring pixels share their planes). The source images,
blurred and subsampled to the stage's resolution, are warped onto every plane
(:func:`mvsformerpp.geometry.warping.homography_warp`, the network's own warp) and the plane with the best
5x5 normalised cross-correlation with the reference, averaged over the source views that see the pixel on
every plane, is the oracle's pick. Printed per stage: the share of pixels where it picks the true plane
(chance 1/32, 1/16, 1/8, 1/4) and the share within one plane. Rows: training recipes' views as training
feeds them (default: the recipes of phases 2, 3 and 4) and, with ``--dtu``, the real DTU pair at 640x512 (its 160x128
ground truth bilinearly upsampled where all four neighbours are valid).

A stage whose views leave even this matcher near chance has nothing to learn from them (phase 2's whole
small photos at stages 3 and 4: docs/model-card.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ["default-lite-synthetic-stage2.yaml", "default-lite-synthetic-stage3.yaml",
           "default-lite-synthetic-stage5.yaml"]


def _blur_down(imgs, f: int):
    """Gaussian blur (sigma f/2) and subsampling by f of [V, C, H, W] images (pixel i <- pixel f*i)."""
    import torch
    import torch.nn.functional as F

    if f == 1:
        return imgs
    k = torch.arange(-2 * f, 2 * f + 1, dtype=torch.float32)
    g = torch.exp(-k**2 / (2 * (0.5 * f) ** 2))
    g = g / g.sum()
    c = imgs.shape[1]
    out = F.conv2d(F.pad(imgs, (2 * f, 2 * f, 0, 0), mode="replicate"), g.view(1, 1, 1, -1).repeat(c, 1, 1, 1),
                   groups=c)
    out = F.conv2d(F.pad(out, (0, 0, 2 * f, 2 * f), mode="replicate"), g.view(1, 1, -1, 1).repeat(c, 1, 1, 1),
                   groups=c)
    return out[:, :, ::f, ::f]


def _box(x, r: int = 2):
    import torch.nn.functional as F

    shape = x.shape
    return F.avg_pool2d(x.reshape(-1, *shape[-2:])[None], 2 * r + 1, 1, r, count_include_pad=False)[0].reshape(shape)


def oracle_counts(imgs, Ks, Es, depth, depth_min: float, depth_max: float, generator) -> np.ndarray:
    """[4, 3] per stage: (pixels where the oracle picks the true plane, within one plane, pixels scored).
    ``imgs`` [V, 3, H, W] in [0, 1] (view 0 the reference), ``Ks`` [V, 3, 3], ``Es`` [V, 4, 4], ``depth`` [H, W]
    the reference's true depth (0 = unknown)."""
    import torch

    from mvsformerpp.geometry.warping import homography_warp, projection_4x4
    from mvsformerpp.models.inputs import stage_projections
    from mvsformerpp.models.presets import get_config
    from mvsformerpp.training.parallax import plane_steps

    cfg = get_config("lite")
    steps = plane_steps(cfg.num_hypotheses, cfg.hypothesis_ratio) * (1 / depth_min - 1 / depth_max)
    projs = stage_projections(Es, Ks)
    out = np.zeros((4, 3))
    for s, D in enumerate(cfg.num_hypotheses):
        f = 2 ** (3 - s)
        im, d = _blur_down(imgs, f), depth[::f, ::f]
        P = projs[f"stage{s + 1}"][0]
        ref_proj = projection_4x4(P[0, 0], P[0, 1])[None]
        offset = float(torch.rand((), generator=generator)) - 0.5
        true = int(torch.randint(0, D, (), generator=generator))
        inv = 1 / d.clamp(min=1e-12) + (torch.arange(D, dtype=torch.float32).view(D, 1, 1) - true - offset) * steps[s]
        planes = (1 / inv.clamp(min=1e-12))[None]
        cost, seen = 0.0, 0.0
        for v in range(1, len(imgs)):
            src_proj = projection_4x4(P[v, 0], P[v, 1])[None]
            warped = homography_warp(torch.cat([im[v:v + 1], torch.ones_like(im[v:v + 1, :1])], 1), src_proj,
                                     ref_proj, planes)[0]
            inside = warped[3].min(0).values > 0.999  # in view on every plane
            a, b = warped[:3], im[0][:, None].expand_as(warped[:3])
            ma, mb = _box(a), _box(b)
            ncc = (_box(a * b) - ma * mb) / ((_box(a * a) - ma**2) * (_box(b * b) - mb**2) + 1e-8).sqrt()
            cost = cost - ncc.mean(0) * inside
            seen = seen + inside.float()
        pick = cost.argmin(0)
        ok = (d > 0) & (inv.min(0).values > 0) & (seen > 0)
        out[s] = (float((pick == true)[ok].sum()), float(((pick - true).abs() <= 1)[ok].sum()), float(ok.sum()))
    return out


def recipe_counts(recipe: str, samples: int, generator) -> np.ndarray:
    import torch

    from mvsformerpp.data.base import SampleKey
    from mvsformerpp.training.config import load_config
    from mvsformerpp.training.datasets import build_datasets

    config = load_config(recipe)
    train, _ = build_datasets(config)
    sizes = list(config.resolutions) or [(config.height, config.width)]
    total = np.zeros((4, 3))
    for k, index in enumerate(np.linspace(0, len(train) - 1, samples).astype(np.int64)):
        h, w = sizes[k % len(sizes)]
        vs = train.views(SampleKey(int(index), int(h), int(w)))
        imgs = torch.stack([torch.from_numpy(v.image.astype(np.float32) / 255).permute(2, 0, 1) for v in vs.views])
        total += oracle_counts(imgs, np.stack([v.K for v in vs.views]), np.stack([v.E for v in vs.views]),
                               torch.from_numpy(vs.views[0].depth.astype(np.float32)), vs.depth_min, vs.depth_max,
                               generator)
    return total


def dtu_counts(draws: int, generator) -> np.ndarray:
    import torch
    from stage_losses import dtu_pair_inputs  # bench/ is on the path when a bench script runs

    from mvsformerpp.evaluation.grids import from_coarse_grid

    total = np.zeros((4, 3))
    for images, Ks, Es, depth_min, depth_max, gt in dtu_pair_inputs():
        H, W = images.shape[-2:]
        depth = torch.from_numpy(from_coarse_grid(gt, H // gt.shape[0], order=1))  # depth pixel j on pixel 4j
        for _ in range(draws):
            total += oracle_counts(images, Ks, Es, depth, depth_min, depth_max, generator)
    return total


def main() -> None:
    import torch

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recipes", nargs="*",
                   help="training recipes or YAML configs (default: the recipes of phases 2, 3 and 4)")
    p.add_argument("--samples", type=int, default=48, help="training samples per recipe (default 48)")
    p.add_argument("--dtu", action="store_true", help="add the real DTU pair at 640x512")
    args = p.parse_args()
    rows = {r: None for r in (args.recipes or [str(ROOT / "configs" / name) for name in RECIPES])}
    print(f"{'views':48s} " + " ".join(f"{'stage ' + str(s):>13s}" for s in range(1, 5)))
    print(f"{'(true plane / within one plane)':48s} " + " ".join(f"{c:>13s}" for c in ("1/32", "1/16", "1/8", "1/4")))
    generator = torch.Generator().manual_seed(0)
    if args.dtu:
        rows["DTU pair 640x512"] = "dtu"
    for name, kind in rows.items():
        counts = dtu_counts(4, generator) if kind == "dtu" else recipe_counts(name, args.samples, generator)
        n = np.maximum(counts[:, 2], 1)
        print(f"{Path(name).name:48s} " + " ".join(f"{a:6.2f}/{b:<6.2f}" for a, b in zip(counts[:, 0] / n,
                                                                                         counts[:, 1] / n)), flush=True)


if __name__ == "__main__":
    main()
