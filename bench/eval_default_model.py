"""Quality of a set of weights (default: the shipped ones) on held-out synthetic scenes and the real checks.

    python bench/eval_default_model.py [--checkpoint RUN/checkpoints/best.safetensors] [--out DIR]
                                       [--json quality.json] [--scenes 4] [--skip-real] [--calibrate]
                                       [--only CHECK ...]

``--calibrate`` first chooses the fusion confidence thresholds for the weights on synthetic scenes of
other seeds (``calibrate_fusion_conf``) and fuses with them; ``tools/ship_default_weights.py --quality``
stores them in the shipped record. Without it, the shipped weights fuse with their recorded
thresholds and other weights with the presets'.

Synthetic: ``--scenes`` scenes of the training style on seeds no run trains on, and as many of the
held-out style, each as whole small photos and as windows of 400-2400 px photos (``*_windows``), and
as many rooms seen by a walking handheld camera at 640x480 (``synthetic_rooms``: indoor video, with the
median AbsRel), the same rooms with every wall and ceiling painted one colour (``synthetic_rooms_painted``:
large surfaces with nothing to match, as in real rooms) (see ``bench/model_quality.py``);
real: the DTU pair with ground-truth depth (tests/data/dtu_pair) and the Middlebury temple of the demo.
Prints one table and writes the JSON. ``--only`` runs a subset of the checks (names as the JSON's keys
without ``synthetic_``: ``train heldout train_windows heldout_windows rooms rooms_painted dtu_pair temple``),
the same functions with the same seeds, for a short experiment's snapshots.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

CHECKS = ("train", "heldout", "train_windows", "heldout_windows", "rooms", "rooms_painted", "dtu_pair", "temple")


def main() -> None:
    from model_quality import (  # bench/ is on the path when a bench script runs
        SYNTHETIC_KINDS,
        calibrate_fusion_conf,
        dtu_pair_quality,
        kind_name,
        synthetic_quality,
        temple_quality,
    )

    from mvsformerpp.pipelines.demo import DEMO_CONFIG
    from mvsformerpp.pipelines.network import run_weights
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig
    from mvsformerpp.utils.allocator import tune_allocator
    from mvsformerpp.utils.atomic import atomic_write_text

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--checkpoint", help="lite weights to evaluate (default: the shipped weights)")
    p.add_argument("--out", help="work folder (default: a temporary one)")
    p.add_argument("--json", help="write the results here")
    p.add_argument("--scenes", type=int, default=4, help="synthetic scenes per style (default: 4)")
    p.add_argument("--skip-real", action="store_true", help="only the synthetic scenes")
    p.add_argument("--calibrate", action="store_true", help="calibrate the fusion thresholds first")
    p.add_argument("--only", nargs="+", choices=CHECKS, help="run only these checks (default: all)")
    args = p.parse_args()
    only = set(args.only or CHECKS) - ({"dtu_pair", "temple"} if args.skip_real else set())
    tune_allocator()
    config = ReconstructConfig(preset="lite", checkpoint=args.checkpoint, num_views=5, fusion="normal")
    print(run_weights(config).description)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        results: dict = {"weights": run_weights(config).description}
        t = time.perf_counter()
        demo = None if args.checkpoint is None else dataclasses.replace(DEMO_CONFIG, checkpoint=args.checkpoint)
        if args.calibrate:
            calibration = calibrate_fusion_conf(out / "calibration", config)
            results["calibration"] = calibration
            confs = calibration["fusion_conf"]
            print(f"calibrated fusion thresholds: {confs}")
            config = dataclasses.replace(config, fusion_conf=confs["normal"])
            demo = dataclasses.replace(demo or DEMO_CONFIG, fusion_conf=confs["dynamic"])
        for style, sensor_width in SYNTHETIC_KINDS:
            name = kind_name(style, sensor_width)
            if name in only:
                results[f"synthetic_{name}"] = synthetic_quality(out / f"synth_{name}", config, style=style,
                                                                 scenes=args.scenes, sensor_width=sensor_width)
        # indoor video: rooms seen by a walking handheld camera, at a depth camera's 640x480
        for name, walls in (("rooms", 0.0), ("rooms_painted", 1.0)):
            if name in only:
                results[f"synthetic_{name}"] = synthetic_quality(out / f"synth_{name}", config, style="train",
                                                                 layout="room", plain_walls=walls,
                                                                 scenes=args.scenes, height=480, width=640)
        if "dtu_pair" in only:
            results["dtu_pair"] = dtu_pair_quality(Path(__file__).resolve().parents[1] / "tests/data/dtu_pair",
                                                   out / "dtu_pair", config)
        if "temple" in only:
            results["temple"] = temple_quality(out / "temple", config=demo)
        results["wall_s"] = round(time.perf_counter() - t, 1)
    for key in ("synthetic_train", "synthetic_heldout", "synthetic_train_windows", "synthetic_heldout_windows",
                "synthetic_rooms", "synthetic_rooms_painted"):
        if key not in results:
            continue
        r = results[key]
        print(f"{key:25s} within 1% of range {100 * r['within_1pct']:5.1f}%   within 10% of depth "
              f"{100 * r['within_10pct_depth']:5.1f}%   median AbsRel {r['median_abs_rel']:.3f}   accuracy "
              f"{_pct(r['accuracy_pct'])}   completeness {_pct(r['completeness_pct'])} of the scene depth")
    print("confidence calibration (training style, windows): share of pixels / within 1% of the range per bin")
    for row in results.get("synthetic_train_windows", {}).get("confidence_calibration", []):
        within = "  -  " if row["within_1pct"] is None else f"{100 * row['within_1pct']:5.1f}%"
        print(f"  conf {row['conf'][0]:.1f}-{row['conf'][1]:.1f}: {100 * row['share']:5.1f}% of pixels, {within}")
    if "dtu_pair" in results:
        r = results["dtu_pair"]
        print(f"{'dtu_pair':25s} within 4 mm {100 * r['within_4mm']:5.1f}%   within 8 mm {100 * r['within_8mm']:5.1f}%"
              f"   within 10% of depth {100 * r['within_10pct']:5.1f}%   grid ratio 8 px {r['grid_ratio']:.2f}, "
              f"32 px {r['grid_ratio_32']:.2f}")
    if "temple" in results:
        r = results["temple"]
        print(f"{'temple':25s} {r['points']} points, {100 * r['inside_box']:.1f}% inside the box, "
              f"{100 * r['on_silhouette']:.1f}% on the silhouettes, grid ratio 8 px {r['grid_ratio']:.2f}, "
              f"32 px {r['grid_ratio_32']:.2f}")
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n")


def _pct(x) -> str:
    return "  n/a" if x is None else f"{x:5.2f}%"


if __name__ == "__main__":
    main()
