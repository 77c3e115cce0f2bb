"""Benchmark: seconds per view of ``reconstruct`` with the default ``lite`` network, this tree beside another.

What a user waits for: ``mvsformerpp reconstruct`` end to end (feature cache, network, depth and preview
files; no fusion), the shipped weights, synthetic scenes of 5 photos at each ``--sizes`` (photo size; the
working resolution follows the command's defaults, so 1200x1600 photos run at 1152x1536), every view the
reference once. With ``--baseline DIR`` (another checkout of this repository, e.g. ``git worktree add DIR
<commit>``) both trees run the same scenes in fresh processes, alternated over ``--rounds``; the table
gives the best round of each, their ratio and how far this tree's depth maps are from the baseline's
(largest difference over the scene's depth range: float rounding only, when the weights are the same).

    PYTHONPATH=src python bench/bench_lite.py [--baseline DIR] [--sizes 480x640 1200x1600] [--rounds 2]
        [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIRST_SEED = 5_100_000  # no training run uses these seeds


def run_tree(tree: Path, scene: Path, out: Path) -> float:
    """Seconds per view of ``reconstruct`` from the sources of ``tree`` (its depth time over its views)."""
    env = {**os.environ, "PYTHONPATH": str(tree / "src")}
    cmd = [sys.executable, "-m", "mvsformerpp", "reconstruct", str(scene), "-o", str(out), "--fusion", "none",
           "--quiet"]
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    timings = json.loads((out / "summary.json").read_text())["timings"]
    return timings["depth_s"] / timings["views_computed"]


def depth_gap(a: Path, b: Path) -> float:
    """Largest |depth_a - depth_b| over the scene's depth range, over all views."""
    from mvsformerpp.io.pfm import read_pfm

    gaps = []
    for pa in sorted((a / "depth_est").glob("*.pfm")):
        da, db = read_pfm(pa), read_pfm(b / "depth_est" / pa.name)
        valid = (da > 0) & (db > 0)
        span = float(da[valid].max() - da[valid].min()) if valid.any() else 1.0
        gaps.append(float(np.abs(da - db).max()) / max(span, 1e-12))
    return max(gaps)


def weights_sha(tree: Path) -> str:
    return json.loads((tree / "src/mvsformerpp/assets/weights/default.json").read_text())["sha256"][:12]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", type=Path, metavar="DIR", help="another checkout to time beside this tree")
    ap.add_argument("--sizes", nargs="+", default=["480x640", "1200x1600"], help="photo sizes HxW")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of both trees, alternated (best counts)")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    a = ap.parse_args()
    from mvsformerpp.synth import generate_scene
    from mvsformerpp.utils.atomic import atomic_write_text

    trees = {"this": ROOT} | ({"baseline": a.baseline.resolve()} if a.baseline else {})
    for name, tree in trees.items():
        if not (tree / "src" / "mvsformerpp").is_dir():
            raise SystemExit(f"{name} tree {tree} has no src/mvsformerpp: give a checkout of this repository")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for k, size in enumerate(a.sizes):
            H, W = (int(x) for x in size.split("x"))
            scene = generate_scene(work / f"scene_{size}", seed=FIRST_SEED + k, num_views=5, height=H, width=W,
                                   style="train")
            seconds = {name: [] for name in trees}
            for r in range(a.rounds):
                for name, tree in trees.items():
                    seconds[name].append(run_tree(tree, scene, work / f"{size}_{name}_{r}"))
            row = {"size": size, **{f"{name}_s_per_view": min(s) for name, s in seconds.items()}}
            if a.baseline:
                row["speedup"] = row["baseline_s_per_view"] / row["this_s_per_view"]
                row["depth_gap"] = depth_gap(work / f"{size}_this_0", work / f"{size}_baseline_0")
            rows.append(row)
    print(f"reconstruct with the default lite weights, 5 views per scene, best of {a.rounds}, "
          f"{os.cpu_count()} CPUs; weights {', '.join(f'{n} {weights_sha(t)}' for n, t in trees.items())}")
    print(f"{'photos':>10s} {'this s/view':>12s}" + (f" {'baseline':>9s} {'speed-up':>9s} {'depth gap':>10s}"
                                                      if a.baseline else ""))
    for r in rows:
        line = f"{r['size']:>10s} {r['this_s_per_view']:12.2f}"
        if a.baseline:
            line += f" {r['baseline_s_per_view']:9.2f} {r['speedup']:8.2f}x {r['depth_gap']:10.1e}"
        print(line)
    if a.json:
        atomic_write_text(a.json, json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
