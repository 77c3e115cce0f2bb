"""Benchmark: ``reconstruct --precision bf16`` (or ``auto``) against fp32 on this machine, speed and the depth
error it adds.

Synthetic scenes with exact depth (``mvsformerpp.synth``, training style, seeds no run trains on) at
640x480, 5 views each, reconstructed end to end with the shipped weights (no fusion), the two
``--precisions`` (default fp32 and bf16) alternated per scene; best of the rounds. Prints per scene the
wall time of each precision and their ratio, the share of pixels within 1 % of the depth range for each,
and the second precision's depth's distance from the first's (median and 99th percentile, as a share of
the range).

    PYTHONPATH=src python bench/bench_precision.py [--precisions fp32 bf16] [--scenes 3] [--rounds 2]
        [--size 480 640] [--json PATH]

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

FIRST_SEED = 5_000_000  # the quality bench's seeds: no training run uses them


def scene_row(scene: Path, work: Path, rounds: int, precisions: tuple[str, str]) -> dict:
    """Times and depth errors of both precisions on one scene."""
    base, other = precisions
    seconds = {p: [] for p in precisions}
    for _ in range(rounds):
        for prec in precisions:
            out = work / f"{scene.name}_{prec}_{len(seconds[prec])}"
            t0 = time.perf_counter()
            reconstruct(scene, out, ReconstructConfig(precision=prec, fusion="none"), quiet=True)
            seconds[prec].append(time.perf_counter() - t0)
    within, gap = {p: [] for p in precisions}, []
    for gt_path in sorted((scene / "depth_gt").glob("*.pfm")):
        gt = read_pfm(gt_path)
        valid = gt > 0
        span = float(gt[valid].max() - gt[valid].min())
        est = {p: read_pfm(work / f"{scene.name}_{p}_0" / "depth_est" / gt_path.name)[valid] for p in precisions}
        for p in precisions:
            within[p].append(float(np.mean(np.abs(est[p] - gt[valid]) < 0.01 * span)))
        gap.append(np.abs(est[other] - est[base]) / span)
    gap = np.concatenate(gap)
    return {"scene": scene.name, **{f"{p}_s": min(seconds[p]) for p in precisions},
            "speedup": min(seconds[base]) / min(seconds[other]),
            **{f"{p}_within_1pct": float(np.mean(within[p])) for p in precisions},
            "gap_median": float(np.median(gap)), "gap_p99": float(np.percentile(gap, 99))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--precisions", nargs=2, default=("fp32", "bf16"), metavar=("BASE", "OTHER"),
                    choices=("auto", "fp32", "bf16", "fp16"))
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--size", type=int, nargs=2, default=(480, 640), metavar=("H", "W"))
    ap.add_argument("--json", type=Path, help="write the rows here")
    a = ap.parse_args()
    if a.precisions[0] == a.precisions[1]:
        ap.error(f"--precisions needs two different precisions to compare, got {a.precisions[0]} twice")
    if a.scenes < 1 or a.rounds < 1:
        ap.error(f"--scenes and --rounds must be at least 1, got {a.scenes} and {a.rounds}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for k in range(a.scenes):
            scene = generate_scene(work / f"scene_{k}", seed=FIRST_SEED + k, num_views=5, height=a.size[0],
                                   width=a.size[1], style="train")
            rows.append(scene_row(Path(scene), work, a.rounds, tuple(a.precisions)))
    print(f"reconstruct, shipped weights, 5 views at {a.size[1]}x{a.size[0]}, best of {a.rounds}; "
          f"{platform.processor() or platform.machine()}, native bf16: {', '.join(sorted(cpu_bf16_flags())) or 'none'}")
    base, other = a.precisions
    print(f"{'scene':10s} {base + ' s':>8s} {other + ' s':>8s} {'speed-up':>9s} {base + ' <1%':>9s} "
          f"{other + ' <1%':>9s} {f'|{other}-{base}| median':>19s} {'p99':>8s}")
    for r in rows:
        print(f"{r['scene']:10s} {r[base + '_s']:8.1f} {r[other + '_s']:8.1f} {r['speedup']:8.2f}x "
              f"{100 * r[base + '_within_1pct']:8.2f}% {100 * r[other + '_within_1pct']:8.2f}% "
              f"{100 * r['gap_median']:18.3f}% {100 * r['gap_p99']:7.3f}%")
    if a.json:
        atomic_write_text(a.json, json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
