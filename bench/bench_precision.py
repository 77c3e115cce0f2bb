"""Benchmark: ``reconstruct --precision bf16`` against fp32 on this machine, speed and the depth error it adds.

Synthetic scenes with exact depth (``mvsformerpp.synth``, training style, seeds no run trains on) at
640x480, 5 views each, reconstructed end to end with the shipped weights (no fusion), fp32 and bf16
alternated per scene; best of the rounds. Prints per scene the wall time of each precision and their
ratio, the share of pixels within 1 % of the depth range for each, and the bf16 depth's distance from
the fp32 depth (median and 99th percentile, as a share of the range).

    PYTHONPATH=src python bench/bench_precision.py [--scenes 3] [--rounds 2] [--size 480 640] [--json PATH]

On a CPU without native bf16 (no ``avx512_bf16`` / ``amx_bf16`` in ``lscpu``) bf16 is emulated and slow.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct
from mvsformerpp.synth import generate_scene
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.precision import cpu_bf16_flags

PRECISIONS = ("fp32", "bf16")
FIRST_SEED = 5_000_000  # the quality bench's seeds: no training run uses them


def scene_row(scene: Path, work: Path, rounds: int) -> dict:
    """Times and depth errors of both precisions on one scene."""
    seconds = {p: [] for p in PRECISIONS}
    for _ in range(rounds):
        for prec in PRECISIONS:
            out = work / f"{scene.name}_{prec}_{len(seconds[prec])}"
            t0 = time.perf_counter()
            reconstruct(scene, out, ReconstructConfig(precision=prec, fusion="none"), quiet=True)
            seconds[prec].append(time.perf_counter() - t0)
    within, gap = {p: [] for p in PRECISIONS}, []
    for gt_path in sorted((scene / "depth_gt").glob("*.pfm")):
        gt = read_pfm(gt_path)
        valid = gt > 0
        span = float(gt[valid].max() - gt[valid].min())
        est = {p: read_pfm(work / f"{scene.name}_{p}_0" / "depth_est" / gt_path.name)[valid] for p in PRECISIONS}
        for p in PRECISIONS:
            within[p].append(float(np.mean(np.abs(est[p] - gt[valid]) < 0.01 * span)))
        gap.append(np.abs(est["bf16"] - est["fp32"]) / span)
    gap = np.concatenate(gap)
    return {"scene": scene.name, **{f"{p}_s": min(seconds[p]) for p in PRECISIONS},
            "speedup": min(seconds["fp32"]) / min(seconds["bf16"]),
            **{f"{p}_within_1pct": float(np.mean(within[p])) for p in PRECISIONS},
            "gap_median": float(np.median(gap)), "gap_p99": float(np.percentile(gap, 99))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--size", type=int, nargs=2, default=(480, 640), metavar=("H", "W"))
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for k in range(a.scenes):
            scene = generate_scene(work / f"scene_{k}", seed=FIRST_SEED + k, num_views=5, height=a.size[0],
                                   width=a.size[1], style="train")
            rows.append(scene_row(Path(scene), work, a.rounds))
    print(f"reconstruct, shipped weights, 5 views at {a.size[1]}x{a.size[0]}, best of {a.rounds}; "
          f"{platform.processor() or platform.machine()}, native bf16: {', '.join(sorted(cpu_bf16_flags())) or 'none'}")
    print(f"{'scene':10s} {'fp32 s':>8s} {'bf16 s':>8s} {'speed-up':>9s} {'fp32 <1%':>9s} {'bf16 <1%':>9s} "
          f"{'|bf16-fp32| median':>19s} {'p99':>8s}")
    for r in rows:
        print(f"{r['scene']:10s} {r['fp32_s']:8.1f} {r['bf16_s']:8.1f} {r['speedup']:8.2f}x "
              f"{100 * r['fp32_within_1pct']:8.1f}% {100 * r['bf16_within_1pct']:8.1f}% "
              f"{100 * r['gap_median']:18.2f}% {100 * r['gap_p99']:7.2f}%")
    if a.json:
        atomic_write_text(a.json, json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
