"""Per-stage cross-entropy of weights on the validation views of training recipes (eval mode).

    python bench/stage_losses.py NAME=WEIGHTS ... [--recipe NAME=CONFIG ...] [--samples 48]

Each weights file (a ``lite`` safetensors checkpoint, or ``shipped`` for the weights in the package) is
scored on the first ``--samples`` validation samples of each recipe (default: the phase-2 recipe's whole
small photos and the phase-3 recipe's windows of high-resolution photos), with the recipe's validation
size. Chance levels are ln 32, ln 16, ln 8 and ln 4. This is the experiment of the model card: the fine
stages (3 and 4) learn only where neighbouring depth planes are far enough apart in the image.
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
    from mvsformerpp.training.trainer import validate

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("weights", nargs="+", metavar="NAME=WEIGHTS", help="weights to score ('shipped' for the package's)")
    p.add_argument("--recipe", action="append", default=[], metavar="NAME=CONFIG", help="recipes whose views to use")
    p.add_argument("--samples", type=int, default=48, help="validation samples per recipe (default 48)")
    args = p.parse_args()
    weights = _pairs(args.weights, "weights")
    recipes = _pairs(args.recipe, "--recipe") if args.recipe else {k: str(v) for k, v in RECIPES.items()}
    device = torch.device("cpu")
    chance = [math.log(n) for n in (32, 16, 8, 4)]
    print(f"{'weights':24s} {'views':24s} {'stage 1':>8s} {'stage 2':>8s} {'stage 3':>8s} {'stage 4':>8s} "
          f"{'abs_rel':>8s}")
    print(f"{'(chance)':24s} {'':24s} " + " ".join(f"{c:8.3f}" for c in chance))
    for wname, path in weights.items():
        model = load_shipped() if path == "shipped" else load_model(path)
        model.to(device)
        for rname, recipe in recipes.items():
            config = dataclasses.replace(load_config(recipe), val_samples=args.samples)
            _, val = build_datasets(config)
            m = validate(model, val, config, device, tuple(model.config.loss_weights))
            print(f"{wname:24s} {rname:24s} " + " ".join(f"{m[f'val_stage{s}']:8.3f}" for s in range(1, 5))
                  + f" {m['abs_rel']:8.4f}", flush=True)


if __name__ == "__main__":
    main()
