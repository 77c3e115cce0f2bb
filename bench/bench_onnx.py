"""Benchmark: ``reconstruct`` with onnxruntime (CPU) beside PyTorch eager, seconds per view and peak memory.

What a user waits for: ``mvsformerpp reconstruct --fusion none`` end to end (network build, feature cache,
depth and preview files) on a synthetic scene of 5 photos, every view the reference once, 5 views per
depth map, in fresh processes alternated over ``--rounds`` (the table gives each backend's best round, its CPU time
per view and the peak RSS of its process). PyTorch runs as the command does by default (``--precision auto``); the
onnxruntime backend runs a model exported once beforehand (the export is not timed). The cases:

* ``lite``: the shipped weights, 480x640 photos (working resolution 640x480);
* ``paper``: random weights of the paper network (seed 0, a checkpoint written once), 512x640 and
  1152x1536 photos (the latter takes many minutes on 2 cores: run it alone, under ``nice``).

``auto`` picks onnxruntime only where it is clearly faster (``mvsformerpp.pipelines.backend.MEASURED``,
filled from this table).

    PYTHONPATH=src python bench/bench_onnx.py [--cases lite:480x640 paper:512x640 paper:1152x1536]
        [--rounds 2] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FIRST_SEED = 5_200_000  # no training run uses these seeds
BACKENDS = ("torch", "onnxruntime")


def run_reconstruct(scene: Path, out: Path, preset: str, backend: str, checkpoint: Path | None,
                    model: Path | None) -> dict:
    """One ``reconstruct`` in a fresh process: seconds per view (depth time over views) and its peak RSS (GB)."""
    cmd = [sys.executable, "-m", "mvsformerpp", "reconstruct", str(scene), "-o", str(out), "--fusion", "none",
           "--quiet", "--preset", preset, "--backend", backend]
    cmd += ["--checkpoint", str(checkpoint)] if checkpoint else []
    cmd += ["--onnx-model", str(model)] if model else []
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr.read().decode()[-3000:]}")
    timings = json.loads((out / "summary.json").read_text())["timings"]
    views = timings["views_computed"]
    return {"s_per_view": timings["depth_s"] / views, "peak_gb": usage.ru_maxrss / 1e6,
            "cpu_s_per_view": (usage.ru_utime + usage.ru_stime) / views, "wall_s": time.perf_counter() - t}


def paper_checkpoint(path: Path) -> Path:
    """Random weights of the paper network (seed 0), written once."""
    import torch

    from mvsformerpp.models import build_model, save_checkpoint

    torch.manual_seed(0)
    return save_checkpoint(build_model("paper"), path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["lite:480x640", "paper:512x640", "paper:1152x1536"],
                    help="PRESET:HxW photo sizes")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of both backends, alternated (best counts)")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    a = ap.parse_args()
    from mvsformerpp.pipelines.export_onnx import OnnxExportConfig, export_onnx
    from mvsformerpp.synth import generate_scene
    from mvsformerpp.utils.atomic import atomic_write_text

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        checkpoint = paper_checkpoint(work / "paper.safetensors") if any(c.startswith("paper")
                                                                           for c in a.cases) else None
        models: dict[str, Path] = {}
        for k, case in enumerate(a.cases):
            preset, size = case.split(":")
            H, W = (int(x) for x in size.split("x"))
            ckpt = checkpoint if preset == "paper" else None
            if preset not in models:
                models[preset] = export_onnx(work / f"onnx_{preset}", OnnxExportConfig(
                    preset=preset, checkpoint=None if ckpt is None else str(ckpt)), quiet=True).folder
            scene = generate_scene(work / f"scene_{k}", seed=FIRST_SEED + k, num_views=5, height=H, width=W,
                                   style="train")
            runs = {b: [] for b in BACKENDS}
            for r in range(a.rounds):
                for b in BACKENDS if r % 2 == 0 else BACKENDS[::-1]:
                    runs[b].append(run_reconstruct(scene, work / f"out_{k}_{b}_{r}", preset, b, ckpt,
                                                   models[preset] if b == "onnxruntime" else None))
            row = {"preset": preset, "photos": size}
            for b in BACKENDS:
                row[f"{b}_s_per_view"] = min(x["s_per_view"] for x in runs[b])
                row[f"{b}_cpu_s_per_view"] = min(x["cpu_s_per_view"] for x in runs[b])
                row[f"{b}_peak_gb"] = min(x["peak_gb"] for x in runs[b])
            row["load_average"] = os.getloadavg()[0]
            row["torch_over_onnxruntime"] = row["torch_s_per_view"] / row["onnxruntime_s_per_view"]
            rows.append(row)
            print(json.dumps(row), flush=True)
    print(f"\nreconstruct, 5 photos, 5 views per depth map, best of {a.rounds} round(s), {os.cpu_count()} CPUs; "
          "PyTorch at --precision auto, onnxruntime on the CPU provider (fp32)")
    print(f"{'preset':>7} {'photos':>10} {'torch s/view':>13} {'ort s/view':>11} {'torch/ort':>10} "
          f"{'torch cpu s':>12} {'ort cpu s':>10} {'torch GB':>9} {'ort GB':>7} {'load':>5}")
    for r in rows:
        print(f"{r['preset']:>7} {r['photos']:>10} {r['torch_s_per_view']:13.2f} {r['onnxruntime_s_per_view']:11.2f} "
              f"{r['torch_over_onnxruntime']:9.2f}x {r['torch_cpu_s_per_view']:12.2f} "
              f"{r['onnxruntime_cpu_s_per_view']:10.2f} {r['torch_peak_gb']:9.2f} {r['onnxruntime_peak_gb']:7.2f} "
              f"{r['load_average']:5.1f}")
    print("s/view: depth time over views (wall); cpu s: the whole process's CPU time over views (model build and "
          "files included); load: the 1-minute load average at the end of the case (a shared machine)")
    if a.json:
        atomic_write_text(a.json, json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
