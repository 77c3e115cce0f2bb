"""Benchmark: what a synthetic training sample costs to make, shuffled one by one and in scene batches.

A synthetic recipe renders its samples while it trains (``mvsformerpp.data.synthetic``); on a GPU machine
the data workers, not the network, can set the pace. Per size, the first batches of an epoch are made in
one process as a data worker makes them, once with samples shuffled one by one and once with
``synthetic_scene_batches`` (whole scenes in a row, each view rendered once for all of them);
the table gives seconds and rendered views per sample and the ratio, and what a step of the recipe's
batch would wait for its data with ``--workers`` processes (the batch rounded up to whole scenes for the
scene batches).

    PYTHONPATH=src python bench/bench_data.py [--recipe configs/default-lite-synthetic-large-crops.yaml]
        [--sizes 256x320 384x512 512x640] [--samples 10] [--workers 14] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def cost(recipe: str, height: int, width: int, samples: int, scene_batches: bool) -> dict:
    """Seconds and renderings per sample of the first ``samples`` samples of epoch 0's order."""
    import mvsformerpp.synth as synth
    from mvsformerpp.data.samplers import MultiScaleBatchSampler
    from mvsformerpp.training.config import load_config
    from mvsformerpp.training.datasets import build_datasets
    from mvsformerpp.training.trainer import shuffle_block

    base = load_config(recipe, {})
    views = base.synthetic_views_per_scene
    batch = views * math.ceil(samples / views) if scene_batches else samples
    cfg = load_config(recipe, {"synthetic_scene_batches": scene_batches, "batch_size": batch})
    train, _ = build_datasets(cfg)
    order = next(iter(MultiScaleBatchSampler(len(train), batch, [(height, width)], seed=cfg.seed,
                                             block=shuffle_block(cfg))))[:samples]
    renders = [0]
    real = synth.render_view

    def counted(scene, cam):
        renders[0] += 1
        return real(scene, cam)

    synth.render_view = counted
    try:
        t = time.perf_counter()
        for key in order:
            train[key]
        seconds = time.perf_counter() - t
    finally:
        synth.render_view = real
    return {"s_per_sample": seconds / len(order), "renders_per_sample": renders[0] / len(order),
            "recipe_batch": base.batch_size, "views_per_scene": views}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recipe", default=str(ROOT / "configs" / "default-lite-synthetic-large-crops.yaml"))
    ap.add_argument("--sizes", nargs="+", default=["256x320", "384x512", "512x640"], help="crop sizes HxW")
    ap.add_argument("--samples", type=int, default=10, help="samples timed per size and order")
    ap.add_argument("--workers", type=int, default=14, help="data workers of the step estimate")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    a = ap.parse_args()
    from mvsformerpp.utils.atomic import atomic_write_text

    rows = []
    for size in a.sizes:
        h, w = (int(x) for x in size.split("x"))
        plain, scenes = (cost(a.recipe, h, w, a.samples, on) for on in (False, True))
        batch, views = plain["recipe_batch"], plain["views_per_scene"]
        whole = views * math.ceil(batch / views)
        rows.append({"size": size, "plain": plain, "scene_batches": scenes,
                     "speedup": plain["s_per_sample"] / scenes["s_per_sample"],
                     "step_wait_s": {"plain": plain["s_per_sample"] * batch / a.workers,
                                     "scene_batches": scenes["s_per_sample"] * whole / a.workers}})
    print(f"synthetic samples of {Path(a.recipe).name}, {a.samples} per size and order, one process "
          f"({os.cpu_count()} CPUs); data wait per step: the recipe's batch of {batch} ({whole} in scene "
          f"batches) over {a.workers} workers")
    print(f"{'crop':>9} {'shuffled s/sample':>17} {'renders':>8} {'scenes s/sample':>16} {'renders':>8} "
          f"{'speed-up':>9} {'step wait':>10} {'scenes':>7}")
    for r in rows:
        p, s = r["plain"], r["scene_batches"]
        print(f"{r['size']:>9} {p['s_per_sample']:17.2f} {p['renders_per_sample']:8.2f} {s['s_per_sample']:16.2f} "
              f"{s['renders_per_sample']:8.2f} {r['speedup']:8.2f}x {r['step_wait_s']['plain']:9.2f}s "
              f"{r['step_wait_s']['scene_batches']:6.2f}s")
    if a.json:
        atomic_write_text(a.json, json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
