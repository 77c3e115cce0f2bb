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
checkpoint stored; ``--same-training`` keeps the training facts of the record shipped now. With ``--run``
the record names the run's training data (``training_data``: the synthetic generator, the sources and
licences of a texture library, the real scenes and the teacher of their labels) and keeps folder names,
not paths of the training machine, in its config.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

FILE_NAME = "mvsformerpp-lite-synthetic.safetensors"


def training_data(config: dict) -> list[str]:
    """The data a run's ``config.yaml`` trained on, in words (read from the texture library's manifest and the
    labels' ``labels.json`` where those folders are still there)."""
    out = []
    if config.get("recipe") == "synthetic":
        options = config.get("synthetic_options") or {}
        out.append(f"synthetic scenes of {config.get('synthetic_source')} with options "
                   f"{ {k: v for k, v in options.items() if k != 'textures'} }")
        library = options.get("textures")
        if library:
            manifest = Path(library) / "manifest.json"
            entries = json.loads(manifest.read_text())["textures"] if manifest.is_file() else []
            sources: dict = {}
            for e in entries:
                key = (e["source"], e["licence"], e.get("author", ""))
                sources[key] = sources.get(key, 0) + 1
            parts = [f"{n} textures from {src} ({lic}{', ' + who if who else ''})"
                     for (src, lic, who), n in sources.items()]
            out.append(f"texture library {Path(library).name}: " + "; ".join(parts))
        else:
            out.append("photo textures: scikit-image's sample photographs")
    else:
        out.append(f"{config.get('recipe')} data set")
    for scene in config.get("real_scenes") or []:
        out.append(f"real scene {Path(scene).name} (its photos and cameras; no depth)")
    labels = config.get("real_labels")
    if labels:
        info = Path(labels) / "labels.json"
        teacher = json.loads(info.read_text()) if info.is_file() else {}
        out.append(f"teacher depth labels {Path(labels).name} of the real scenes: {teacher.get('teacher', '?')} "
                   f"({teacher.get('checkpoint', '?')}, kept where views agree)")
    if config.get("self_supervised_weight"):
        out.append(f"self-supervision on the real scenes (weight {config['self_supervised_weight']})")
    return out


def strip_paths(config: dict) -> dict:
    """The run's config with folder names for the data paths of the training machine."""
    config = dict(config)
    for key in ("init_checkpoint", "real_labels", "data_root", "dtu_root"):
        if config.get(key):
            config[key] = Path(config[key]).name
    if config.get("real_scenes"):
        config["real_scenes"] = [Path(p).name for p in config["real_scenes"]]
    options = dict(config.get("synthetic_options") or {})
    if options.get("textures"):
        options["textures"] = Path(options["textures"]).name
        config["synthetic_options"] = options
    return config


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
        config = yaml.safe_load((run / "config.yaml").read_text())
        info["training_data"] = training_data(config)
        # the record names the starting weights and the data folders, not paths on the training machine
        info["training_config"] = strip_paths(config)
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
