"""Per-stage cross-entropy of weights on the validation views of training recipes (eval mode).

    python bench/stage_losses.py NAME=WEIGHTS ... [--recipe NAME=CONFIG ...] [--samples 48]

Each weights file (a ``lite`` safetensors checkpoint, or ``shipped`` for the weights in the package) is
scored on the first ``--samples`` validation samples of each recipe (default: the phase-2 recipe's whole
small photos and the phase-3 recipe's windows of high-resolution photos), with the recipe's validation
size: per-stage cross-entropy (chance: ln 32, ln 16, ln 8, ln 4), abs_rel, and per stage the share of
pixels whose depth lies within one of that stage's plane spacings of the truth, and the share whose
truth lies inside the stage's hypothesis window at all (:func:`stage_scores`).
This is the experiment of the model card: the fine stages (3 and 4) learn only where neighbouring depth
planes are far enough apart in the image. ``--dtu`` adds the same shares on the real DTU pair
(tests/data/dtu_pair: 640x512, each view the reference once, its 160x128 ground truth brought to every
stage's grid by subsampling or repetition; no cross-entropy there).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPES = {"whole photos (phase 2)": ROOT / "configs" / "default-lite-synthetic-stage2.yaml",
           "windows (phase 3)": ROOT / "configs" / "default-lite-synthetic-stage3.yaml"}


def _pairs(items: list[str], what: str) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise SystemExit(f"error: {what} must be NAME=PATH, got {item!r}")
        out[name] = value
    return out


def main() -> None:
    import torch

    from mvsformerpp.models.checkpoint import load_model
    from mvsformerpp.models.shipped import load_shipped
    from mvsformerpp.training.config import load_config
    from mvsformerpp.training.datasets import build_datasets

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("weights", nargs="+", metavar="NAME=WEIGHTS", help="weights to score ('shipped' for the package's)")
    p.add_argument("--recipe", action="append", default=[], metavar="NAME=CONFIG", help="recipes whose views to use")
    p.add_argument("--samples", type=int, default=48, help="validation samples per recipe (default 48)")
    p.add_argument("--dtu", action="store_true", help="also score the real DTU pair (shares only)")
    args = p.parse_args()
    weights = _pairs(args.weights, "weights")
    recipes = _pairs(args.recipe, "--recipe") if args.recipe else {k: str(v) for k, v in RECIPES.items()}
    device = torch.device("cpu")
    chance = [math.log(n) for n in (32, 16, 8, 4)]
    print(f"{'':49s} {'cross-entropy of stage':>35s} {'':8s} {'share within one plane at stage':>35s} "
          f"{'share whose truth is in the window':>35s}")
    print(f"{'weights':24s} {'views':24s} " + " ".join(f"{s:>8d}" for s in range(1, 5)) + f" {'abs_rel':>8s} "
          + " ".join(f"{s:>8d}" for s in range(1, 5)) + " " + " ".join(f"{s:>8d}" for s in range(1, 5)))
    print(f"{'(chance)':24s} {'':24s} " + " ".join(f"{c:8.3f}" for c in chance))
    for wname, path in weights.items():
        model = load_shipped() if path == "shipped" else load_model(path)
        model.to(device)
        for rname, recipe in recipes.items():
            config = dataclasses.replace(load_config(recipe), val_samples=args.samples)
            _, val = build_datasets(config)
            ce, rel, resolved, inside = stage_scores(model, val, config, device)
            print(f"{wname:24s} {rname:24s} " + " ".join(f"{v:8.3f}" for v in ce)
                  + f" {rel:8.4f} " + " ".join(f"{100 * r:7.1f}%" for r in resolved)
                  + " " + " ".join(f"{100 * r:7.1f}%" for r in inside), flush=True)
        if args.dtu:
            rel, resolved, inside = dtu_stage_scores(model)
            print(f"{wname:24s} {'DTU pair 640x512':24s} " + " ".join(f"{'-':>8s}" for _ in range(4))
                  + f" {rel:8.4f} " + " ".join(f"{100 * r:7.1f}%" for r in resolved)
                  + " " + " ".join(f"{100 * r:7.1f}%" for r in inside), flush=True)


def stage_scores(model, dataset, config, device):
    """(per-stage cross-entropy, abs_rel of the final depth, per-stage share within one plane) on the first
    ``val_samples`` samples in eval mode (the temperatures of inference).

    The share: valid ground-truth pixels whose stage depth lies within one of that stage's plane spacings
    of the truth (in inverse depth). The cross-entropy counts only the pixels whose truth falls inside the
    stage's hypotheses, a set that changes with the earlier stages; this share counts every pixel. Fine
    stages that learned nothing leave stage 4 at stage 2's precision, so its share falls far below stage
    2's; fine stages that work keep it close."""
    import numpy as np
    import torch

    from mvsformerpp.data.base import SampleKey
    from mvsformerpp.models.loss import cascade_loss
    from mvsformerpp.training.trainer import _to, collate

    model.prepare_for_inference()
    h, w = config.val_height or config.height, config.val_width or config.width
    counts, ce, rel = np.zeros((3, 4)), [], []
    with torch.no_grad():
        for i in range(min(config.val_samples, len(dataset))):
            batch = _to(collate([dataset[SampleKey(i, h, w, 0)]]), device)
            out = model(batch["imgs"], batch["proj_matrices"], batch["depth_values"])
            _, per_stage = cascade_loss(out, batch["depth_gt"], batch["mask"])
            ce.append([float(per_stage[f"stage{s}"]) for s in range(1, 5)])
            gt4, m4 = batch["depth_gt"]["stage4"], batch["mask"]["stage4"] > 0.5
            rel.append(float(((out["depth"] - gt4).abs() / gt4.clamp(min=1e-6))[m4 & (gt4 > 0)].mean()))
            counts += _stage_counts(out, batch["depth_gt"], {k: m > 0.5 for k, m in batch["mask"].items()})
    n = np.maximum(counts[2], 1)
    return np.mean(ce, 0), float(np.mean(rel)), list(counts[0] / n), list(counts[1] / n)


def _stage_counts(out, depth_gt, masks):
    """[3, 4]: per stage, the valid pixels within one plane spacing of the truth (in inverse depth), those
    whose truth lies inside the stage's window (as the loss bins it: half a gap beyond each end), all valid."""
    import numpy as np

    counts = np.zeros((3, 4))
    for s in range(4):
        o, gt = out[f"stage{s + 1}"], depth_gt[f"stage{s + 1}"]
        valid = masks[f"stage{s + 1}"] & (gt > 0)
        step = (1 / o["depth_values"][:, 1] - 1 / o["depth_values"][:, 0]).abs()
        err = (1 / o["depth"].float() - 1 / gt.clamp(min=1e-6)).abs()
        d = o["depth_values"]
        half = (d[:, 1] - d[:, 0]).abs() / 2
        within = (gt >= d.min(dim=1).values - half) & (gt <= d.max(dim=1).values + half)
        counts[:, s] = (float((err[valid] < step[valid]).sum()), float(within[valid].sum()), float(valid.sum()))
    return counts


def dtu_pair_inputs():
    """The DTU pair (tests/data/dtu_pair) as the network takes it at 640x512, once per reference view: yields
    (images [2, 3, H, W] in [0, 1], Ks [2, 3, 3], extrinsics [2, 4, 4], depth_min, depth_max, the reference's
    160x128 ground-truth depth), the reference first."""
    import numpy as np
    import torch

    from mvsformerpp.io.images import read_image
    from mvsformerpp.io.mvsnet import read_cam
    from mvsformerpp.io.pfm import read_pfm

    pair = ROOT / "tests" / "data" / "dtu_pair"
    cams = [read_cam(pair / f"{i:08d}_cam.txt") for i in (0, 1)]
    images = [torch.from_numpy(read_image(pair / f"rect_{i + 1:03d}_0_r5000.png").astype(np.float32) / 255)
              .permute(2, 0, 1) for i in (0, 1)]
    for ref in (0, 1):
        order = (ref, 1 - ref)
        Ks = np.stack([np.diag([4.0, 4.0, 1.0]) @ cams[i].K for i in order])  # the cams' K is for 160x128
        yield (torch.stack([images[i] for i in order]), Ks, np.stack([cams[i].extrinsic for i in order]),
               cams[ref].depth_min, cams[ref].depth_max, read_pfm(pair / f"depth_map_{ref:04d}.pfm"))


def dtu_stage_scores(model):
    """(abs_rel of the final depth, per-stage share within one plane, per-stage share with the truth in the
    window) on the DTU pair at 640x512, each view the reference once (the other its source)."""
    import numpy as np
    import torch

    from mvsformerpp.evaluation.grids import from_coarse_grid
    from mvsformerpp.models.inputs import normalize, stage_projections

    counts, rel = np.zeros((3, 4)), []
    model.prepare_for_inference()
    for images, Ks, Es, depth_min, depth_max, gt in dtu_pair_inputs():
        depth_values = torch.tensor([[depth_min, depth_max]], dtype=torch.float32)
        with torch.no_grad():
            out = model(normalize(images)[None], stage_projections(Es, Ks), depth_values)
        depth_gt = {}
        for s in range(4):
            h = out[f"stage{s + 1}"]["depth"].shape[-2]
            f = h / gt.shape[0]
            k = round(1 / f) if f < 1 else round(f)
            g = gt[::k, ::k] if f < 1 else from_coarse_grid(gt, k)  # depth pixel j on pixel k j
            depth_gt[f"stage{s + 1}"] = torch.from_numpy(np.ascontiguousarray(g))[None]
        counts += _stage_counts(out, depth_gt, {k: torch.ones_like(v, dtype=torch.bool) for k, v in depth_gt.items()})
        g4 = depth_gt["stage4"]
        rel.append(float(((out["depth"] - g4).abs() / g4.clamp(min=1e-6))[g4 > 0].mean()))
    n = np.maximum(counts[2], 1)
    return float(np.mean(rel)), list(counts[0] / n), list(counts[1] / n)


if __name__ == "__main__":
    main()
