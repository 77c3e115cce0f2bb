"""``mvsformerpp train RECIPE_OR_CONFIG -o RUN_DIR``: train or fine-tune the network."""

from __future__ import annotations

import argparse

# Command-line options that set a config field directly: option dest -> field.
_FIELDS = {"data_root": "data_root", "train_list": "train_list", "val_list": "val_list", "preset": "preset",
           "checkpoint": "init_checkpoint", "max_steps": "max_steps", "epochs": "epochs",
           "batch_size": "batch_size", "height": "height", "width": "width", "views": "num_views", "seed": "seed",
           "save_every": "save_every", "device": "device", "precision": "precision"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="train or fine-tune the network (DTU, BlendedMVS, synthetic scenes)",
        description="Train MVSFormer++ from a recipe (dtu, blended_finetune, synthetic) or a YAML config of the "
        "same fields. Writes RUN_DIR/config.yaml, metrics.jsonl, tb/ and checkpoints/{last,best}.safetensors. "
        "Several processes: torchrun --nproc-per-node G -m mvsformerpp train ...",
    )
    p.add_argument("config", metavar="RECIPE_OR_CONFIG", help="dtu | blended_finetune | synthetic | a YAML file")
    p.add_argument("-o", "--output", required=True, metavar="RUN_DIR", help="run folder")
    p.add_argument("--data-root", help="data set root (DTU; BlendedMVS for blended_finetune)")
    p.add_argument("--train-list", help="file listing the training scans/scenes")
    p.add_argument("--val-list", help="file listing the validation scans/scenes")
    p.add_argument("--preset", choices=("lite", "paper", "paper_finetune"), help="network preset")
    p.add_argument("--checkpoint", metavar="INIT", help="weights to start from")
    p.add_argument("--max-steps", type=int, help="optimiser steps (default: epochs x batches per epoch)")
    p.add_argument("--epochs", type=int)
    p.add_argument("--batch-size", type=int, help="global batch size (all processes)")
    p.add_argument("--height", type=int, help="training height (single-scale)")
    p.add_argument("--width", type=int, help="training width (single-scale)")
    p.add_argument("--views", type=int, help="views per sample")
    p.add_argument("--seed", type=int)
    p.add_argument("--save-every", type=int, metavar="N", help="write checkpoints/last.* every N steps")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"),
                   help="auto (the default): CUDA when a CUDA device is present, else the CPU")
    p.add_argument("--precision", choices=("fp32", "bf16", "fp16"))
    p.add_argument("--resume", action="store_true", help="continue the run in RUN_DIR from its last checkpoint")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config field (YAML value), e.g. --set lr=1e-4 --set loss_weights=[0,0,0,1]")
    p.set_defaults(func=run, on_memory_error="lower --batch-size, --height/--width or --views",
                   on_interrupt="continue the run with the same command and --resume (from its last checkpoint)")


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.train import run_training
    from mvsformerpp.training.config import load_config, parse_overrides

    overrides = {field: getattr(args, dest) for dest, field in _FIELDS.items() if getattr(args, dest) is not None}
    overrides.update(parse_overrides(args.set))
    config = load_config(args.config, overrides)
    from pathlib import Path

    recipe_file = [args.config] if Path(args.config).is_file() else []
    summary = run_training(config, args.output, resume=args.resume, inputs=recipe_file)
    val = summary.get("last_validation") or {}
    shown = ", ".join(f"{k} {v:.4g}" for k, v in val.items() if k in ("val_loss", "mae", "abs_rel"))
    print(f"trained {summary['steps']} steps ({summary['bad_steps']} skipped); {shown}; "
          f"weights: {summary['checkpoint']}")
    return 0
