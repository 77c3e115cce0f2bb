"""Eval-forward time and peak memory of the paper network (5 views), against the compute floor.

``first s`` is the first forward after building the model (what the official numbers measure),
``time s`` the next one (steady state, as when a scene is reconstructed view after view); the
ratio to the floor uses the steady state.

Each configuration runs in a fresh subprocess (clean peak RSS). The floor is the forward's FLOPs
(torch.utils.flop_counter) divided by this machine's measured sgemm rate, both measured in this run.
Reference numbers of the official code on a 2-core machine (fp32): 12-18 s and 2.1 GB peak RSS at
512x640, 100 s and 5.15 GB at 1152x1536.

    python bench/bench_model.py [--sizes 512x640 1152x1536] [--device cpu|cuda] [--precision fp32|bf16]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

OFFICIAL = {"512x640": (15.0, 2.1), "1152x1536": (100.0, 5.15)}  # seconds (midpoint of 12-18), GB


def sgemm_gflops(n: int = 2048, reps: int = 3, trials: int = 7) -> float:
    """This machine's fp32 matrix-multiply rate: the best of several trials (a busy moment only
    lowers a trial, so the best is the most faithful floor and the strictest ratio)."""
    import torch

    a, b = torch.randn(n, n), torch.randn(n, n)
    a @ b
    best = 0.0
    for _ in range(trials):
        t = time.perf_counter()
        for _ in range(reps):
            a @ b
        best = max(best, 2 * n**3 * reps / (time.perf_counter() - t) / 1e9)
    return best


def child(size: str, device: str, precision: str, views: int, count_flops: bool) -> dict:
    import resource

    import torch

    from mvsformerpp.models import build_model

    H, W = (int(x) for x in size.split("x"))
    torch.manual_seed(0)
    model = build_model("paper").eval().to(device)
    imgs = torch.randn(1, views, 3, H, W, device=device)
    proj = {}
    for s, f in enumerate((8, 4, 2, 1)):
        P = torch.zeros(1, views, 2, 4, 4, device=device)
        P[:, :, 0] = torch.eye(4)
        P[:, :, 0, 0, 3] = torch.arange(views) * 50.0
        P[:, :, 1, :3, :3] = torch.tensor([[1.2 * W / f, 0, W / 2 / f], [0, 1.2 * W / f, H / 2 / f], [0, 0, 1]])
        proj[f"stage{s + 1}"] = P
    dv = torch.tensor([[425.0, 935.0]], device=device)
    dtype = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}[precision]
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    def run():
        with torch.no_grad(), torch.autocast(device, dtype=dtype or torch.float32, enabled=dtype is not None):
            out = model(imgs, proj, dv)
        if device == "cuda":
            torch.cuda.synchronize()
        return out

    if device == "cuda":
        run()
        torch.cuda.reset_peak_memory_stats()
    t = time.perf_counter()
    run()
    cold = time.perf_counter() - t
    t = time.perf_counter()
    run()
    seconds = time.perf_counter() - t
    res = {"size": size, "device": device, "precision": precision, "seconds": seconds, "cold_seconds": cold,
           "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
           "rss_after_build_gb": rss0 / 1e6}
    if device == "cuda":
        res["peak_cuda_gb"] = torch.cuda.max_memory_allocated() / 1e9
    if count_flops:
        from torch.utils.flop_counter import FlopCounterMode

        with FlopCounterMode(display=False) as fc:
            run()
        res["gflop"] = fc.get_total_flops() / 1e9
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", default=["512x640", "1152x1536"])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precision", default="fp32", choices=["fp32", "bf16", "fp16"])
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--no-flops", action="store_true", help="skip FLOP counting (it costs one more forward)")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(child(a.child, a.device, a.precision, a.views, not a.no_flops)))
        return
    rate = sgemm_gflops()
    rows = []
    for size in a.sizes:
        cmd = [sys.executable, __file__, "--child", size, "--device", a.device, "--precision", a.precision,
               "--views", str(a.views)] + (["--no-flops"] if a.no_flops else [])
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    rate = max(rate, sgemm_gflops())  # measured before and after the runs; the best one sets the floor
    print(f"sgemm: {rate:.0f} GFLOP/s (cpu, best of the trials before and after the runs)")
    hdr = (f"{'size':>10} {'prec':>5} {'first s':>8} {'time s':>8} {'GFLOP':>7} {'floor s':>8} {'x floor':>8} "
           f"{'peak RSS GB':>11} {'vs official time':>16} {'vs official RSS':>15}")
    print(hdr)
    for r in rows:
        floor = r["gflop"] / rate if "gflop" in r else float("nan")
        off = OFFICIAL.get(r["size"])
        vt = f"{r['cold_seconds'] / off[0]:.2f}x" if off and a.device == "cpu" else "-"
        vm = f"{r['peak_rss_gb'] / off[1]:.2f}x" if off and a.device == "cpu" else "-"
        print(f"{r['size']:>10} {r['precision']:>5} {r['cold_seconds']:>8.2f} {r['seconds']:>8.2f} "
              f"{r.get('gflop', float('nan')):>7.0f} "
              f"{floor:>8.2f} {r['seconds'] / floor:>8.2f} {r['peak_rss_gb']:>11.2f} {vt:>16} {vm:>15}")


if __name__ == "__main__":
    main()
