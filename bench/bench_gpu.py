"""The paper network on a GPU: seconds per view and peak GPU memory, fp32 and bf16, SDPA and FlashAttention-2.

One eval forward of the paper network with 5 views is one depth map (one reference view). Each
configuration runs in a fresh subprocess: two warm-up forwards, then ``--repeats`` timed forwards
(CUDA-synchronised); the peak is ``torch.cuda.max_memory_allocated`` over the timed forwards (and the
allocator's reserved peak, closer to what nvidia-smi shows). The MVSFormer++ paper reports 0.354 s and
5,964 MB per view at 1152x1536 on an RTX A6000; the table puts each row next to them.
``--reconstruct N`` also times ``reconstruct`` end to end on N synthetic views (the per-image feature
cache, I/O and PNG previews included).

    python bench/bench_gpu.py [--size 1152x1536] [--views 5] [--repeats 5] [--json OUT.json]
    python bench/bench_gpu.py --dry-run     # the same code path on the CPU at a small size
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PAPER = {"seconds": 0.354, "memory_mb": 5964, "gpu": "RTX A6000", "size": "1152x1536"}


def child(size: str, views: int, precision: str, backend: str, device: str, repeats: int) -> dict:
    import torch
    from bench_model import synthetic_inputs

    from mvsformerpp.models import build_model

    H, W = (int(x) for x in size.split("x"))
    torch.manual_seed(0)
    model = build_model("paper").eval().to(device)
    model.set_attention_backend(backend)
    imgs, proj, dv = synthetic_inputs(H, W, views, device)
    dtype = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}[precision]
    cuda = device.startswith("cuda")

    def sync():
        if cuda:
            torch.cuda.synchronize()

    def forward():
        with torch.no_grad(), torch.autocast(device.split(":")[0], dtype=dtype or torch.float32,
                                             enabled=dtype is not None):
            out = model(imgs, proj, dv)
        sync()
        return out

    t = time.perf_counter()
    out = forward()
    first = time.perf_counter() - t
    forward()
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = forward()
        times.append(time.perf_counter() - t)
    depth = out["depth"].float()
    res = {"size": size, "views": views, "precision": precision, "backend": backend, "device": device,
           "first_s": first, "seconds": sorted(times)[len(times) // 2], "best_s": min(times),
           "depth_finite": bool(torch.isfinite(depth).all())}
    if cuda:
        res["peak_allocated_mb"] = torch.cuda.max_memory_allocated() / 2**20
        res["peak_reserved_mb"] = torch.cuda.max_memory_reserved() / 2**20
        res["gpu"] = torch.cuda.get_device_name()
    else:
        import resource

        res["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def reconstruct_child(size: str, num_views: int, precision: str, device: str) -> dict:
    """``reconstruct`` end to end on a strip of synthetic views at ``size`` (paper network, random weights)."""
    import torch

    from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct
    from mvsformerpp.synth.strip import generate_strip_scene

    H, W = (int(x) for x in size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        scene = generate_strip_scene(Path(tmp) / "scene", num_views=num_views, height=H, width=W,
                                     with_depth_maps=False)
        cfg = ReconstructConfig(preset="paper", device=device, precision=precision, max_size=max(H, W),
                                num_views=5, fusion="normal")
        if device.startswith("cuda"):
            torch.cuda.reset_peak_memory_stats()
        t = time.perf_counter()
        summary = reconstruct(scene, Path(tmp) / "out", cfg, quiet=True)
        total = time.perf_counter() - t
    res = {"size": size, "views": num_views, "precision": precision, "total_s": total,
           "depth_s_per_view": summary["timings"]["depth_s"] / num_views, "fusion_s": summary["timings"]["fusion_s"],
           "feature_cache": summary["feature_cache"]}
    if device.startswith("cuda"):
        res["peak_allocated_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return res


def run_child(args: list[str]) -> dict | str:
    done = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if done.returncode != 0:
        return (done.stderr.strip().splitlines() or ["failed"])[-1][:200]
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="1152x1536", help="HxW of the network input (default: the paper's 1152x1536)")
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=5, help="timed forwards per configuration (median reported)")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--reconstruct", type=int, default=8, metavar="N",
                    help="also time reconstruct end to end on N synthetic views per precision (0: skip)")
    ap.add_argument("--dry-run", action="store_true",
                    help="check the script on the CPU: 128x160, 3 views, 1 repeat, 3 reconstructed views")
    ap.add_argument("--json", help="write all results here")
    ap.add_argument("--child", nargs=6, help=argparse.SUPPRESS)
    ap.add_argument("--reconstruct-child", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        size, views, precision, backend, device, repeats = a.child
        print(json.dumps(child(size, int(views), precision, backend, device, int(repeats))))
        return
    if a.reconstruct_child:
        size, n, precision, device = a.reconstruct_child
        print(json.dumps(reconstruct_child(size, int(n), precision, device)))
        return
    if a.dry_run:
        a.size, a.views, a.repeats, a.device, a.reconstruct = "128x160", 3, 1, "cpu", min(a.reconstruct, 3)
    elif a.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            sys.exit("no CUDA device visible to torch (a CUDA build of torch is needed); use --dry-run to check "
                     "the script on the CPU")
    from mvsformerpp.models.attention import flash_available

    configs = [("fp32", "sdpa"), ("bf16", "sdpa"), ("bf16", "flash")]
    rows, recon = [], []
    for precision, backend in configs:
        if backend == "flash" and not (a.device.startswith("cuda") and flash_available()):
            rows.append({"precision": precision, "backend": backend,
                         "skipped": "flash_attn is not installed or no CUDA device (pip install 'mvsformerpp[flash]')"})
            continue
        res = run_child(["--child", a.size, str(a.views), precision, backend, a.device, str(a.repeats)])
        rows.append(res if isinstance(res, dict) else {"precision": precision, "backend": backend, "failed": res})
    for precision in ("fp32", "bf16") if a.reconstruct else ():
        res = run_child(["--reconstruct-child", a.size, str(a.reconstruct), precision, a.device])
        recon.append(res if isinstance(res, dict) else {"precision": precision, "failed": res})

    print(f"paper network, {a.size}, {a.views} views, {a.device}"
          + (f" ({rows[0].get('gpu')})" if rows and rows[0].get("gpu") else "")
          + f"; paper: {PAPER['seconds']} s and {PAPER['memory_mb']:,} MB per view on an {PAPER['gpu']}")
    print(f"{'precision':>9} {'attention':>9} {'s/view':>8} {'vs paper':>8} {'first s':>8} "
          f"{'peak MB':>9} {'reserved MB':>11} {'vs paper':>8}")
    for r in rows:
        if "seconds" not in r:
            print(f"{r['precision']:>9} {r['backend']:>9}  {r.get('skipped') or 'failed: ' + r['failed']}")
            continue
        peak = r.get("peak_allocated_mb", r.get("peak_rss_mb", float("nan")))
        print(f"{r['precision']:>9} {r['backend']:>9} {r['seconds']:>8.3f} {r['seconds'] / PAPER['seconds']:>7.2f}x "
              f"{r['first_s']:>8.2f} {peak:>9.0f} {r.get('peak_reserved_mb', float('nan')):>11.0f} "
              f"{peak / PAPER['memory_mb']:>7.2f}x")
    if a.device == "cpu":
        print("(CPU: the peak column is the process's peak RSS)")
    for r in recon:
        if "failed" in r:
            print(f"reconstruct {r['precision']}: failed: {r['failed']}")
            continue
        print(f"reconstruct {r['views']} views at {r['size']} ({r['precision']}): {r['depth_s_per_view']:.3f} s per "
              f"depth map, fusion {r['fusion_s']:.2f} s, total {r['total_s']:.1f} s, feature cache "
              f"{r['feature_cache']['hits']} hits / {r['feature_cache']['misses']} misses"
              + (f", peak {r['peak_allocated_mb']:.0f} MB" if "peak_allocated_mb" in r else ""))
    if a.json:
        from mvsformerpp.utils.atomic import atomic_write_text

        atomic_write_text(Path(a.json), json.dumps({"paper": PAPER, "forward": rows, "reconstruct": recon}, indent=2))


if __name__ == "__main__":
    main()
