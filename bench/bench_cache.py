"""Scene throughput of depth inference with the per-image feature cache vs recomputing per reference view.

Runs the network over the first N views of the bundled temple (or any scene INPUT) twice: once with
the feature cache (each image's DINOv2 + FPN-encoder features computed once) and once with
``cache_mb=0`` (every reference view encodes all of its V images again, as the reference test script
does). Prints a Markdown table and writes JSON with ``--json``.

    PYTHONPATH=src python bench/bench_cache.py --preset lite --images 8 --views 5 --max-size 640
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch

from mvsformerpp.inference.resolution import plan_views
from mvsformerpp.inference.runner import SceneInference
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.images import read_image
from mvsformerpp.pipelines.demo import temple_dir
from mvsformerpp.pipelines.network import build_network
from mvsformerpp.pipelines.reconstruct import ReconstructConfig
from mvsformerpp.pipelines.scene_input import prepare_scene


def run(model, scene, plans, images, args, cache_mb: int) -> dict:
    calls = {"images_encoded": 0}
    encode = model.encode_images

    def counting(imgs):
        calls["images_encoded"] += imgs.shape[0]
        return encode(imgs)

    model.encode_images = counting
    runner = SceneInference(model, scene, plans, lambda i: images[i], num_views=args.views,
                            device=args.device, precision=args.precision, cache_bytes=cache_mb << 20)
    runner.infer(0)  # warm-up (allocator, kernels); not timed
    runner.cache = type(runner.cache)(runner.cache.encode, runner.cache.max_bytes)
    calls["images_encoded"] = 0
    if args.device.startswith("cuda"):
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    for i in range(len(scene)):
        runner.infer(i)
    if args.device.startswith("cuda"):
        torch.cuda.synchronize()
    dt = time.perf_counter() - t0
    model.encode_images = encode
    return {"seconds": dt, "views_per_s": len(scene) / dt, **calls, **runner.cache.stats()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("input", nargs="?", default=str(temple_dir()))
    p.add_argument("--preset", default="lite")
    p.add_argument("--images", type=int, default=8, help="reference views to run (first N of the scene)")
    p.add_argument("--views", type=int, default=5, help="views per depth map")
    p.add_argument("--max-size", type=int, default=640)
    p.add_argument("--device", default="cpu")
    p.add_argument("--precision", default="fp32")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    torch.set_grad_enabled(False)

    cfg = ReconstructConfig(preset=args.preset, device=args.device, precision=args.precision,
                            max_size=args.max_size, num_views=args.views, max_images=args.images)
    scene = prepare_scene(load_scene(args.input), cfg)
    plans = plan_views([(v.width, v.height) for v in scene.views], args.max_size)
    images = [read_image(v.image_path) for v in scene.views]
    model = build_network(cfg)
    results = {
        "cached": run(model, scene, plans, images, args, cache_mb=4096),
        "recompute": run(model, scene, plans, images, args, cache_mb=0),
    }
    speedup = results["recompute"]["seconds"] / results["cached"]["seconds"]
    canvas = f"{plans[0].canvas_width}x{plans[0].canvas_height}"
    dev = torch.cuda.get_device_name() if args.device.startswith("cuda") else platform.processor() or "cpu"
    print(f"\n{len(scene)} reference views, {args.views} views each, canvas {canvas}, preset {args.preset}, "
          f"{args.device} ({dev}), {args.precision}, torch {torch.__version__}, {torch.get_num_threads()} threads\n")
    print("| mode | seconds | views/s | images encoded |")
    print("|---|---|---|---|")
    for name, r in results.items():
        print(f"| {name} | {r['seconds']:.2f} | {r['views_per_s']:.3f} | {r['images_encoded']} |")
    print(f"\nspeed-up with the cache: {speedup:.2f}x")
    if args.json:
        from mvsformerpp.utils.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps({"args": vars(args) | {"json": str(args.json)}, "canvas": canvas,
                                                "device": dev, "results": results, "speedup": speedup}, indent=2))


if __name__ == "__main__":
    main()
