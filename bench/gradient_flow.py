"""Where a training step's gradient goes: per part of the network, the norm of its weights, the norm of its
gradient and their ratio, on training batches of a recipe (training mode, one backward per batch, no
optimiser step); and along the Side View Attention path (ViT tokens -> ``proj`` -> ``upsampler0`` ->
``upsampler1`` -> added to the 1/8 CNN features), the root-mean-square of each block's output, of the
convolution's output before its BatchNorm, and of the gradient arriving there. Then, in eval mode on
``--map-samples`` samples, how much of Side View Attention's output (about its channel means) is a fixed map
per view slot (the reference, each source position) and how much depends on the images.

A part whose ratio is orders of magnitude below the others is one the loss hardly depends on, whatever its
size (AdamW still moves its weights by about the learning rate: compare two checkpoints to see that); the
model card's "Where the training signal goes" has the numbers of the shipped weights.

    PYTHONPATH=src python bench/gradient_flow.py [--checkpoint PATH|shipped] [--config CONFIG.yaml]
                                                 [--size 256 320] [--batches 2] [--map-samples 12]
                                                 [--json PATH]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SVA_PATH = ("proj", "upsampler0", "upsampler1")


def part_name(param: str) -> str:
    """The part a parameter belongs to: the ViT's blocks and the cascade stages one by one, else the module."""
    head = param.split(".")
    return ".".join(head[:2]) if head[0] == "fusions" or head[:2] == ["vit", "blocks"] else head[0]


def measure(checkpoint: str | None, config: str, size: tuple[int, int], batches: int,
            map_samples: int = 12) -> dict:
    import torch

    from mvsformerpp.data import SampleKey
    from mvsformerpp.models.loss import cascade_loss
    from mvsformerpp.models.shipped import shipped_weights_path
    from mvsformerpp.training.config import load_config
    from mvsformerpp.training.datasets import build_datasets
    from mvsformerpp.training.trainer import build_training_model, collate

    h, w = size
    init = str(shipped_weights_path()) if checkpoint in (None, "shipped") else checkpoint
    cfg = load_config(config, {"height": h, "width": w, "resolutions": [[h, w]], "device": "cpu",
                               "init_checkpoint": init})
    train, _ = build_datasets(cfg)
    torch.manual_seed(cfg.seed)
    model = build_training_model(cfg).train()
    sva = model.decoder_vit
    chain: dict[str, list[float]] = {}

    def record(name: str):
        def hook(_module, _inputs, out):
            chain.setdefault(f"{name} output", []).append(float(out.detach().pow(2).mean().sqrt()))
            out.register_hook(lambda g: chain.setdefault(f"{name} gradient", []).append(float(g.pow(2).mean().sqrt())))
        return hook

    handles = []
    for name in SVA_PATH:
        block = sva.get_submodule(name)
        handles.append(block.register_forward_hook(record(name)))
        handles.append(block[0].register_forward_hook(record(f"{name} conv (before BatchNorm)")))
    grads: dict[str, float] = {}
    for b in range(batches):
        samples = [train[SampleKey(b * cfg.batch_size + j, h, w, 0)] for j in range(cfg.batch_size)]
        batch = collate(samples)
        model.zero_grad(set_to_none=True)
        out = model(batch["imgs"], batch["proj_matrices"], batch["depth_values"])
        loss, _ = cascade_loss(out, batch["depth_gt"], batch["mask"], model.config.loss_weights)
        loss.backward()
        for name, p in model.named_parameters():
            if p.grad is not None:
                part = part_name(name)
                grads[part] = grads.get(part, 0.0) + float(p.grad.pow(2).sum()) / batches
    for handle in handles:
        handle.remove()
    slots = slot_shares(model, train, cfg.batch_size, (h, w), map_samples) if map_samples else None
    parts = {}
    for name, p in model.named_parameters():
        row = parts.setdefault(part_name(name), {"params": 0, "weight_norm": 0.0})
        row["params"] += p.numel()
        row["weight_norm"] += float(p.detach().pow(2).sum())
    for name, row in parts.items():
        row["weight_norm"] **= 0.5
        row["grad_norm"] = grads[name] ** 0.5 if name in grads else None
        row["ratio"] = None if row["grad_norm"] is None else row["grad_norm"] / max(row["weight_norm"], 1e-30)
    return {"checkpoint": checkpoint or "shipped", "config": config, "size": list(size), "batches": batches,
            "parts": parts, "sva_path": {k: sum(v) / len(v) for k, v in chain.items()}, "sva_maps": slots}


def slot_shares(model, train, batch_size: int, size: tuple[int, int], samples: int) -> dict:
    """Side View Attention's output over ``samples`` samples in eval mode: the share of its variance about
    the channel means that one fixed map per view slot explains, and the rest (what depends on the images)."""
    import torch

    from mvsformerpp.data import SampleKey
    from mvsformerpp.training.trainer import collate

    maps = []
    hook = model.decoder_vit.register_forward_hook(lambda _m, _i, out: maps.append(out.detach()))
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            for a in range(0, samples, batch_size):
                keys = range(10_000 + a, 10_000 + min(a + batch_size, samples))
                batch = collate([train[SampleKey(k, *size, 0)] for k in keys])
                model(batch["imgs"], batch["proj_matrices"], batch["depth_values"])
    finally:
        hook.remove()
        model.train(was_training)
    views = int(batch["imgs"].shape[1])
    x = torch.cat(maps).view(samples, views, *maps[0].shape[1:])  # [samples, view slot, C, h, w]
    return {"samples": samples, "views": views, **variance_shares(x)}


def variance_shares(x) -> dict:
    """Maps ``x`` [samples, view slot, C, h, w]: of their variance about the channel means, the share one
    fixed map per view slot explains (``slot_maps``) and the rest (``image_dependent``)."""
    total = float((x - x.mean(dim=(0, 1, 3, 4), keepdim=True)).pow(2).mean())
    rest = float((x - x.mean(0, keepdim=True)).pow(2).mean()) / total
    return {"slot_maps": 1 - rest, "image_dependent": rest}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", help="lite weights (default: the shipped ones)")
    ap.add_argument("--config", default=str(ROOT / "configs" / "default-lite-synthetic-stage8.yaml"),
                    help="the training recipe whose batches are used (default: phase 8's)")
    ap.add_argument("--size", type=int, nargs=2, default=(256, 320), metavar=("H", "W"))
    ap.add_argument("--batches", type=int, default=2)
    ap.add_argument("--map-samples", type=int, default=12, help="samples for the view-slot maps (0: skip)")
    ap.add_argument("--json", help="also write the numbers here")
    args = ap.parse_args()
    if args.batches < 1 or args.map_samples < 0:
        ap.error(f"--batches must be at least 1 and --map-samples at least 0, got {args.batches} and "
                 f"{args.map_samples}")
    if min(args.size) < 64 or any(s % 32 for s in args.size):
        ap.error(f"--size must be multiples of 32 of at least 64, got {args.size[0]} {args.size[1]}")
    from mvsformerpp.utils.allocator import tune_allocator

    tune_allocator()
    r = measure(args.checkpoint, args.config, tuple(args.size), args.batches, args.map_samples)
    print(f"{'part':<14} {'weights':>9} {'|w|':>9} {'|g|':>10} {'|g| / |w|':>10}")
    for name, row in sorted(r["parts"].items()):
        g = "-" if row["grad_norm"] is None else f"{row['grad_norm']:.3e}"
        ratio = "-" if row["ratio"] is None else f"{row['ratio']:.2e}"
        print(f"{name:<14} {row['params']:>9} {row['weight_norm']:9.3f} {g:>10} {ratio:>10}")
    print("Side View Attention path, root-mean-square (mean over the batches):")
    for name, v in r["sva_path"].items():
        print(f"  {name:<40} {v:.3e}")
    if r["sva_maps"]:
        m = r["sva_maps"]
        print(f"Side View Attention's output in eval mode ({m['samples']} samples x {m['views']} views), variance "
              f"about its channel means: a fixed map per view slot {100 * m['slot_maps']:.1f} %, the images "
              f"{100 * m['image_dependent']:.1f} %")
    if args.json:
        from mvsformerpp.utils.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(r, indent=1) + "\n")


if __name__ == "__main__":
    main()
