"""``mvsformerpp train RECIPE_OR_CONFIG -o RUN_DIR``: train or fine-tune the network."""

from __future__ import annotations

import argparse
from pathlib import Path

from mvsformerpp.training.config import TrainConfig
from mvsformerpp.utils.config_flags import add_config_flags

FLAGS = ("data_root", "train_list", "val_list", "preset", "init_checkpoint", "max_steps", "epochs", "batch_size",
         "height", "width", "num_views", "seed", "save_every", "device", "precision", "real_scenes", "real_labels",
         "self_supervised_weight")
"""The :class:`~mvsformerpp.training.config.TrainConfig` fields with a flag of their own (any field: ``--set``)."""


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
    add_config_flags(p, TrainConfig, FLAGS, default_notes=dict.fromkeys(FLAGS, "the recipe's"),
                     **dict.fromkeys(FLAGS))
    p.add_argument("--resume", action="store_true", help="continue the run in RUN_DIR from its last checkpoint")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any config field (YAML value), e.g. --set lr=1e-4 --set loss_weights=[0,0,0,1]")
    p.set_defaults(func=run, on_memory_error="lower --batch-size, --height/--width or --views",
                   on_interrupt="continue the run with the same command and --resume (from its last checkpoint)")


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.train import run_training
    from mvsformerpp.training.config import load_config, parse_overrides

    overrides = {name: getattr(args, name) for name in FLAGS if getattr(args, name) is not None}
    overrides.update(parse_overrides(args.set))
    config = load_config(args.config, overrides)
    recipe_file = [args.config] if Path(args.config).is_file() else []
    summary = run_training(config, args.output, resume=args.resume, inputs=recipe_file)
    val = summary.get("last_validation") or {}
    shown = ", ".join(f"{k} {v:.4g}" for k, v in val.items() if k in ("val_loss", "mae", "abs_rel"))
    print(f"trained {summary['steps']} steps ({summary['bad_steps']} skipped); {shown}; "
          f"weights: {summary['checkpoint']}")
    return 0
