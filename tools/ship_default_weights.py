"""Turn a training checkpoint into the weights shipped with the package (fp16 safetensors + record).

    python tools/ship_default_weights.py RUN_DIR/checkpoints/best.safetensors --run RUN_DIR \
        [--quality quality.json] [--info key=value ...]

Writes src/mvsformerpp/assets/weights/<file> and default.json (size, SHA-256, the training facts given,
the run's config.yaml and last metrics, and the measured quality when --quality is given; a quality file
made with ``--calibrate`` also gives the fusion confidence thresholds ``reconstruct`` uses with them).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

FILE_NAME = "mvsformerpp-lite-synthetic.safetensors"


def main() -> None:
    import yaml

    from mvsformerpp.models.checkpoint import load_model
    from mvsformerpp.models.shipped import WEIGHTS_DIR, write_shipped

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint")
    p.add_argument("--run", help="the training run folder (config.yaml, metrics.jsonl)")
    p.add_argument("--quality", help="JSON written by bench/eval_default_model.py")
    p.add_argument("--info", action="append", default=[], metavar="KEY=VALUE", help="extra facts for the record")
    args = p.parse_args()
    model = load_model(args.checkpoint)
    info: dict = dict(kv.split("=", 1) for kv in args.info)
    if args.run:
        run = Path(args.run)
        info["training_config"] = yaml.safe_load((run / "config.yaml").read_text())
        init = info["training_config"].get("init_checkpoint")
        if init:  # the record names the starting weights, not a path on the training machine
            info["training_config"]["init_checkpoint"] = Path(init).name
        rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines() if line.strip()]
        train_rows = [r for r in rows if "loss" in r]
        val_rows = [r for r in rows if any(k.startswith("val") for k in r)]
        info["last_training_row"] = train_rows[-1] if train_rows else None
        info["last_validation_row"] = val_rows[-1] if val_rows else None
    if args.quality:
        quality = json.loads(Path(args.quality).read_text())
        calibration = quality.pop("calibration", None)
        info["quality"] = quality
        if calibration is not None:  # bench/eval_default_model.py --calibrate: the thresholds fusion uses
            info["fusion_conf"] = calibration["fusion_conf"]
            info["fusion_calibration"] = calibration
    path = write_shipped(model, "lite", WEIGHTS_DIR, FILE_NAME, info)
    print(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MiB) and {WEIGHTS_DIR / 'default.json'}")


if __name__ == "__main__":
    main()
