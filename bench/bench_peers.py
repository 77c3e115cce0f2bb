"""This package's weights beside IterMVS and PatchmatchNet on the real checks, same inputs, one table.

    PYTHONPATH=src python bench/bench_peers.py --itermvs CLONE --patchmatchnet CLONE [--checkpoint WEIGHTS]
        [--scenes 2] [--skip-temple] [--skip-rooms] [--out DIR] [--json PATH]

Each method gets the same photos, cameras, depth ranges and source views (the reference and its best
neighbours, 5 views; 2 on the DTU pair), on the CPU:

- the DTU pair (``tests/data/dtu_pair``, 640x512, ground-truth depth in mm): shares within 4 mm, 8 mm and
  10 % (``bench/model_quality.py``: ``dtu_pair_metrics``);
- the Middlebury temple of the demo (16 views, 640x480): every view's depth fused by this package's
  ``dynamic`` fusion, at the confidence threshold each method's authors use (IterMVS 0.3, PatchmatchNet
  0.5; this package: the one calibrated for its weights), then points, share inside the bounding box and
  share on the silhouettes (``temple_cloud_metrics``); seconds per view;
- rooms seen by a walking handheld camera (synthetic, 640x480, exact depth; drawn and with every wall
  painted one colour, seeds no training run uses): share of pixels within 10 % of the depth and median
  AbsRel, as indoor benchmarks report them.

This package's rows come from the quality harness's own functions (``reconstruct`` with the given weights),
the peers' from ``bench/peers.py`` (their networks imported from the clones; nothing of theirs is in this
repository).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
PEER_CONF = {"itermvs": 0.3, "patchmatchnet": 0.5}
"""Photometric confidence thresholds of the peers' own evaluation scripts (their defaults)."""


def peer_depths(kind, net, scene, views: int = 5, ids=None):
    """(depths, confidences, seconds per view) of ``scene``'s views ``ids`` (all) with their best neighbours."""
    from peers import predict

    from mvsformerpp.io.images import read_image

    depths, confs = [], []
    t = time.perf_counter()
    ids = range(len(scene)) if ids is None else ids
    for i in ids:
        v = scene.views[i]
        sel = [i] + v.neighbors[: views - 1]
        imgs = np.stack([read_image(scene.views[j].image_path) for j in sel])
        d, c = predict(kind, net, imgs, np.stack([scene.views[j].K for j in sel]),
                       np.stack([scene.views[j].extrinsic for j in sel]), v.depth_min, v.depth_max)
        depths.append(d)
        confs.append(c)
    return depths, confs, (time.perf_counter() - t) / max(len(depths), 1)


def room_metrics(scene, depths) -> dict:
    """Within 10 % of the depth and median AbsRel of depth maps against a synthetic scene's depth_gt."""
    from mvsformerpp.io.pfm import read_pfm

    rel = []
    for v, est in zip(scene.views, depths):
        gt = read_pfm(scene.root / "depth_gt" / f"{v.name}.pfm")
        valid = gt > 0
        rel.append(np.abs(est[valid] - gt[valid]) / gt[valid])
    rel = np.concatenate(rel)
    return {"within_10pct_depth": float((rel < 0.1).mean()), "median_abs_rel": float(np.median(rel))}


def main() -> None:
    from model_quality import (  # bench/ is on the path when a bench script runs
        HELDOUT_SEED,
        dtu_pair_metrics,
        dtu_pair_quality,
        synthetic_quality,
        temple_cloud_metrics,
        temple_quality,
    )
    from peers import load_peer

    from mvsformerpp.fusion.config import get_config
    from mvsformerpp.fusion.views import fuse_depth_maps
    from mvsformerpp.io import load_scene
    from mvsformerpp.io.images import read_image
    from mvsformerpp.io.ply import write_ply
    from mvsformerpp.pipelines.demo import DEMO_CONFIG, temple_dir
    from mvsformerpp.pipelines.network import run_weights
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig
    from mvsformerpp.synth import generate_scene

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--itermvs", help="clone of FangjinhuaWang/IterMVS (with checkpoints/)")
    p.add_argument("--patchmatchnet", help="clone of FangjinhuaWang/PatchmatchNet (with checkpoints/)")
    p.add_argument("--checkpoint", help="this package's lite weights (default: the shipped ones)")
    p.add_argument("--scenes", type=int, default=2, help="rooms per kind (default 2)")
    p.add_argument("--skip-temple", action="store_true")
    p.add_argument("--skip-rooms", action="store_true")
    p.add_argument("--out", help="work folder (default: a temporary one)")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args()
    config = ReconstructConfig(preset="lite", checkpoint=args.checkpoint, num_views=5, fusion="normal")
    peers = {k: load_peer(k, c) for k, c in (("itermvs", args.itermvs), ("patchmatchnet", args.patchmatchnet)) if c}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        ours = f"mvsformerpp lite ({Path(args.checkpoint).name if args.checkpoint else 'shipped weights'})"
        print(run_weights(config).description)
        results: dict = {ours: {}, **{k: {} for k in peers}}
        pair_dir = ROOT / "tests" / "data" / "dtu_pair"
        results[ours]["dtu_pair"] = dtu_pair_quality(pair_dir, out / "dtu_pair", config)
        pair_scene = load_scene(out / "dtu_pair" / "input")
        for kind, net in peers.items():
            depths, _, _ = peer_depths(kind, net, pair_scene, views=2)
            results[kind]["dtu_pair"] = dtu_pair_metrics(pair_dir, depths)
        if not args.skip_temple:
            demo = DEMO_CONFIG if args.checkpoint is None else dataclasses.replace(DEMO_CONFIG,
                                                                                   checkpoint=args.checkpoint)
            t = temple_quality(out / "temple", demo)
            results[ours]["temple"] = {**t, "s_per_view": t["depth_s"] / t["views"]}
            temple = load_scene(temple_dir())
            images = [read_image(v.image_path) for v in temple.views]
            for kind, net in peers.items():
                depths, confs, secs = peer_depths(kind, net, temple)
                xyz, rgb = fuse_depth_maps(temple, depths, confs, images,
                                           get_config("dynamic", conf_threshold=PEER_CONF[kind]))
                write_ply(out / f"temple_{kind}.ply", xyz, rgb)
                results[kind]["temple"] = {**temple_cloud_metrics(out / f"temple_{kind}.ply"), "s_per_view": secs}
        if not args.skip_rooms:
            for name, walls in (("rooms", 0.0), ("rooms_painted", 1.0)):
                results[ours][name] = synthetic_quality(out / f"ours_{name}", config, style="train", layout="room",
                                                        plain_walls=walls, scenes=args.scenes, height=480, width=640)
                for kind, net in peers.items():
                    rows = []
                    for k in range(args.scenes):
                        folder = generate_scene(out / f"{kind}_{name}_{k}", seed=HELDOUT_SEED + k, num_views=5,
                                                height=480, width=640, style="train", layout="room",
                                                plain_walls=walls)
                        scene = load_scene(folder)
                        depths, _, _ = peer_depths(kind, net, scene)
                        rows.append((scene, depths))
                    rel_all = [room_metrics(s, d) for s, d in rows]
                    results[kind][name] = {k: float(np.mean([r[k] for r in rel_all])) for k in rel_all[0]}
    print(format_table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float) + "\n")


def format_table(results: dict) -> str:
    """One markdown row per method."""
    def pct(x):
        return f"{100 * x:.1f}" if x is not None else "-"

    lines = ["| method | DTU pair within 4 mm / 8 mm / 10 % | temple: points, in the box, on the silhouettes; "
             "s per view | rooms as drawn: within 10 % / AbsRel | painted rooms: within 10 % / AbsRel |",
             "|---|---|---|---|---|"]
    for method, r in results.items():
        d = r.get("dtu_pair", {})
        cells = [f"{pct(d.get('within_4mm'))} / {pct(d.get('within_8mm'))} / {pct(d.get('within_10pct'))} %"]
        t = r.get("temple")
        cells.append(f"{t['points']:,}, {pct(t['inside_box'])} %, {pct(t['on_silhouette'])} %; {t['s_per_view']:.2f}"
                     if t else "-")
        for name in ("rooms", "rooms_painted"):
            x = r.get(name)
            cells.append(f"{pct(x['within_10pct_depth'])} % / {x['median_abs_rel']:.3f}" if x else "-")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
