"""Turn a training checkpoint into the weights shipped with the package (fp16 safetensors + record).

    python tools/ship_default_weights.py RUN_DIR/checkpoints/best.safetensors --run RUN_DIR \
        [--quality quality.json] [--info key=value ...]
    python tools/ship_default_weights.py src/mvsformerpp/assets/weights/FILE --same-training \
        --quality quality.json     # the same weights again, re-measured (e.g. after a change of the preset);
                                   # without --calibrate in the quality file they keep their fusion thresholds

Writes src/mvsformerpp/assets/weights/<file> and default.json (size, SHA-256, the training facts given,
the run's config.yaml and last metrics, and the measured quality when --quality is given; a quality file
made with ``--calibrate`` also gives the fusion confidence thresholds ``reconstruct`` uses with them).
The file stores the ``lite`` preset's config (what ``reconstruct`` builds for it), whatever the
checkpoint stored; ``--same-training`` keeps the training facts of the record shipped now.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

FILE_NAME = "mvsformerpp-lite-synthetic.safetensors"


def main() -> None:
    import yaml

    from mvsformerpp.models import build_model
    from mvsformerpp.models.checkpoint import load_checkpoint
    from mvsformerpp.models.shipped import SHIPPED_PRESET, WEIGHTS_DIR, shipped_record, write_shipped

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint")
    p.add_argument("--run", help="the training run folder (config.yaml, metrics.jsonl)")
    p.add_argument("--quality", help="JSON written by bench/eval_default_model.py")
    p.add_argument("--info", action="append", default=[], metavar="KEY=VALUE", help="extra facts for the record")
    p.add_argument("--same-training", action="store_true",
                   help="keep the training facts of the weights shipped now (re-shipping them re-measured)")
    args = p.parse_args()
    if args.same_training and args.run:
        p.error("--same-training keeps the shipped record's training facts: leave out --run")
    model = load_checkpoint(build_model(SHIPPED_PRESET), args.checkpoint)
    info: dict = {}
    if args.same_training:  # everything the record says, but what the file itself and a new measurement change
        info = {k: v for k, v in shipped_record().items() if k not in ("file", "preset", "bytes", "sha256")}
    info.update(kv.split("=", 1) for kv in args.info)
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
        if isinstance(quality.get("weights"), str):  # the record names files inside the package, not this machine's
            quality["weights"] = quality["weights"].replace(f"{Path(__file__).resolve().parents[1]}/", "")
        info["quality"] = quality
        if calibration is not None:  # bench/eval_default_model.py --calibrate: the thresholds fusion uses
            info["fusion_conf"] = calibration["fusion_conf"]
            info["fusion_calibration"] = calibration
        elif "fusion_conf" in info:  # measured without --calibrate: the same weights keep their thresholds
            print("kept the shipped fusion thresholds (the quality file was made without --calibrate)")
    path = write_shipped(model, SHIPPED_PRESET, WEIGHTS_DIR, FILE_NAME, info)
    print(f"wrote {path} ({path.stat().st_size / 2**20:.1f} MiB) and {WEIGHTS_DIR / 'default.json'}")


if __name__ == "__main__":
    main()
