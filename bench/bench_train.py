"""Training throughput and peak memory: samples/s of full optimiser steps (forward, backward, AdamW)
for the ``lite`` and ``paper`` presets on synthetic samples, 5 views, batch 1, fp32.

Each preset runs in a fresh subprocess (clean peak RSS). The samples are rendered once before
timing, so the numbers are the network's training step alone (data loading runs in parallel
DataLoader workers in a real run). On CUDA the peak is ``torch.cuda.max_memory_allocated``.

    python bench/bench_train.py [--presets lite paper] [--size 256x320] [--steps 3] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys


def run_one(preset: str, h: int, w: int, steps: int, device: str, precision: str) -> dict:
    import resource
    import time

    import torch

    from mvsformerpp.data import SampleKey
    from mvsformerpp.training import distributed as D
    from mvsformerpp.training.config import load_config
    from mvsformerpp.training.datasets import build_datasets
    from mvsformerpp.training.trainer import _train_step, build_optimizer, build_training_model, collate

    cfg = load_config("synthetic", {"preset": preset, "height": h, "width": w, "num_views": 5, "batch_size": 1,
                                    "device": device, "precision": precision, "synthetic_render_scale": 1.0})
    train, _ = build_datasets(cfg)
    batches = [collate([train[SampleKey(i, h, w, 0)]]) for i in range(steps + 1)]
    info = D.DistInfo(0, 1, 0, torch.device(device))
    model = build_training_model(cfg).to(device).train()
    opt = build_optimizer(model, cfg)
    scaler = torch.amp.GradScaler(device, enabled=precision == "fp16")
    weights = model.config.loss_weights
    _train_step(model, opt, scaler, batches[0], 1, 1, weights, cfg, info.device, info)  # warm-up
    if device == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    t = time.perf_counter()
    for b in batches[1:]:
        _train_step(model, opt, scaler, b, 1, 1, weights, cfg, info.device, info)
    if device == "cuda":
        torch.cuda.synchronize()
    dt = (time.perf_counter() - t) / steps
    peak = (torch.cuda.max_memory_allocated() if device == "cuda"
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
    trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
    return {"preset": preset, "size": f"{h}x{w}", "device": device, "precision": precision,
            "s_per_step": dt, "samples_per_s": 1 / dt, "peak_gb": peak / 1e9, "trainable_params": trainable}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--presets", nargs="+", default=["lite", "paper"])
    p.add_argument("--size", default="256x320")
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--device", default="cpu")
    p.add_argument("--precision", default="fp32")
    p.add_argument("--one", help=argparse.SUPPRESS)
    a = p.parse_args()
    h, w = (int(x) for x in a.size.split("x"))
    if a.one:
        print(json.dumps(run_one(a.one, h, w, a.steps, a.device, a.precision)))
        return
    print(f"{'preset':8} {'size':9} {'device':6} {'prec':5} {'s/step':>8} {'samples/s':>10} {'peak GB':>8}")
    for preset in a.presets:
        out = subprocess.run([sys.executable, __file__, "--one", preset, "--size", a.size, "--steps", str(a.steps),
                              "--device", a.device, "--precision", a.precision], check=True, capture_output=True,
                             text=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        print(f"{r['preset']:8} {r['size']:9} {r['device']:6} {r['precision']:5} {r['s_per_step']:8.2f} "
              f"{r['samples_per_s']:10.3f} {r['peak_gb']:8.2f}", flush=True)


if __name__ == "__main__":
    main()
