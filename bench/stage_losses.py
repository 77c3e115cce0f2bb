"""Per-stage cross-entropy of weights on the validation views of training recipes (eval mode).

    python bench/stage_losses.py NAME=WEIGHTS ... [--recipe NAME=CONFIG ...] [--samples 48]

Each weights file (a ``lite`` safetensors checkpoint, or ``shipped`` for the weights in the package) is
scored on the first ``--samples`` validation samples of each recipe (default: the phase-2 recipe's whole
small photos and the phase-3 recipe's windows of high-resolution photos), with the recipe's validation
size: per-stage cross-entropy (chance: ln 32, ln 16, ln 8, ln 4), abs_rel, and per stage the share of
pixels whose depth lies within one of that stage's plane spacings of the truth, and the share whose
truth lies inside the stage's hypothesis window at all (:func:`stage_scores`).
This is the experiment of the model card: the fine stages (3 and 4) learn only where neighbouring depth
planes are far enough apart in the image.
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
    hits, inside, total, ce, rel = np.zeros(4), np.zeros(4), np.zeros(4), [], []
    with torch.no_grad():
        for i in range(min(config.val_samples, len(dataset))):
            batch = _to(collate([dataset[SampleKey(i, h, w, 0)]]), device)
            out = model(batch["imgs"], batch["proj_matrices"], batch["depth_values"])
            _, per_stage = cascade_loss(out, batch["depth_gt"], batch["mask"])
            ce.append([float(per_stage[f"stage{s}"]) for s in range(1, 5)])
            gt4, m4 = batch["depth_gt"]["stage4"], batch["mask"]["stage4"] > 0.5
            rel.append(float(((out["depth"] - gt4).abs() / gt4.clamp(min=1e-6))[m4 & (gt4 > 0)].mean()))
            for s in range(4):
                o, gt = out[f"stage{s + 1}"], batch["depth_gt"][f"stage{s + 1}"]
                valid = (batch["mask"][f"stage{s + 1}"] > 0.5) & (gt > 0)
                step = (1 / o["depth_values"][:, 1] - 1 / o["depth_values"][:, 0]).abs()
                err = (1 / o["depth"].float() - 1 / gt.clamp(min=1e-6)).abs()
                hits[s] += float((err[valid] < step[valid]).float().sum())
                d = o["depth_values"]  # the stage's window, as the loss bins it (half a gap beyond each end)
                near, far = d.min(dim=1).values, d.max(dim=1).values
                half = (d[:, 1] - d[:, 0]).abs() / 2
                within = (gt >= near - half) & (gt <= far + half)
                inside[s] += float(within[valid].float().sum())
                total[s] += int(valid.sum())
    n = np.maximum(total, 1)
    return np.mean(ce, 0), float(np.mean(rel)), list(hits / n), list(inside / n)


if __name__ == "__main__":
    main()
