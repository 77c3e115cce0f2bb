"""Time and peak memory of ``reconstruct`` and ``fuse`` against the number of views; 1 vs 2 processes.

Synthetic strip scenes (:mod:`mvsformerpp.synth.strip`: a textured plane under a line of cameras)
of 16, 64 and 256 views. Every run is a fresh ``mvsformerpp`` process whose own peak RSS is reported.

- reconstruct: the ``lite`` network (random weights: the timing, not the geometry, is the point) at a
  small working size, fusion included;
- fuse: exact depth maps at ``--fuse-size``, once within a fixed ``--memory-gb`` budget and once with
  the default budget (half of the free memory: every view stays cached);
- 1 vs 2 processes: the same reconstruction as one process (2 threads, then 1) and under
  ``torchrun --nproc-per-node 2`` (1 thread each), on the same cores.

    python bench/bench_scale.py [--views 16 64 256] [--fuse-views 16 64 256] [--size 96x128] [--fuse-size 480x640]
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

MEASURE = ("import resource, sys; from mvsformerpp.cli import main; "
           "from mvsformerpp.utils.allocator import tune_allocator; tune_allocator(); rc = main(sys.argv[1:]); "
           "print('PEAK_RSS_MB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024); sys.exit(rc)")


def run(args: list[str], threads: int = 2, torchrun: int = 0) -> tuple[float, float]:
    """Seconds and peak RSS (MB; the largest rank's under torchrun) of one mvsformerpp command."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    if torchrun:
        with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
            f.write(MEASURE.replace("; ", "\n"))
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(torchrun),
               f.name, *args]
    else:
        cmd = [sys.executable, "-c", MEASURE, *args]
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed: {done.stderr[-2000:]}")
    peaks = [float(line.split()[-1]) for line in (done.stdout + done.stderr).splitlines() if "PEAK_RSS_MB" in line]
    return seconds, max(peaks)


def main() -> None:
    from mvsformerpp.synth.strip import generate_strip_scene

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, nargs="+", default=[16, 64, 256], help="view counts for reconstruct")
    ap.add_argument("--fuse-views", type=int, nargs="+", default=[16, 64, 256], help="view counts for fuse")
    ap.add_argument("--size", default="96x128", help="HxW of the photos for reconstruct")
    ap.add_argument("--fuse-size", default="480x640", help="HxW of the depth maps for fuse")
    ap.add_argument("--memory-gb", type=float, default=0.25, help="the fixed fusion budget")
    ap.add_argument("--ranks-views", type=int, default=16, help="views of the 1 vs 2 processes comparison")
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args()
    H, W = (int(x) for x in a.size.split("x"))
    fH, fW = (int(x) for x in a.fuse_size.split("x"))
    recon = ["--preset", "lite", "--max-size", str(max(H, W)), "--views", "5", "--quiet"]
    rows = {"reconstruct": [], "fuse": [], "ranks": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for n in a.fuse_views:
            depths = generate_strip_scene(tmp / f"depths{n}", num_views=n, height=fH, width=fW)
            row = {"views": n, "megapixels": n * fH * fW / 1e6}
            for name, budget in (("budget", ["--memory-gb", str(a.memory_gb)]), ("default", [])):
                s, rss = run(["fuse", str(depths), "-o", str(tmp / "f.ply"), "--quiet", *budget])
                row[f"{name}_s"], row[f"{name}_rss_mb"] = s, rss
            rows["fuse"].append(row)
            print(json.dumps(row), flush=True)
        for n in a.views:
            scene = generate_strip_scene(tmp / f"photos{n}", num_views=n, height=H, width=W, with_depth_maps=False)
            s, rss = run(["reconstruct", str(scene), "-o", str(tmp / f"rec{n}"), *recon])
            summary = json.loads((tmp / f"rec{n}" / "summary.json").read_text())
            rows["reconstruct"].append({"views": n, "seconds": s, "peak_rss_mb": rss,
                                        "depth_s": summary["timings"]["depth_s"],
                                        "fusion_s": summary["timings"]["fusion_s"],
                                        "cache": summary["feature_cache"]})
            print(json.dumps(rows["reconstruct"][-1]), flush=True)
        n = a.ranks_views
        scene = generate_strip_scene(tmp / "ranks", num_views=n, height=H, width=W, with_depth_maps=False)
        for procs, threads in ((1, 2), (1, 1), (2, 1)):
            args = ["reconstruct", str(scene), "-o", str(tmp / f"ranks{procs}-{threads}"), *recon]
            s, rss = run(args, threads=threads, torchrun=procs if procs > 1 else 0)
            rows["ranks"].append({"processes": procs, "threads": threads, "views": n, "seconds": s,
                                  "peak_rss_mb_per_process": rss})
            print(json.dumps(rows["ranks"][-1]), flush=True)

    print(f"\nreconstruct (lite, {a.size}, 5 views per depth map, fusion normal)")
    print(f"{'views':>6} {'total s':>8} {'depth s':>8} {'s/view':>7} {'fusion s':>8} {'peak RSS MB':>11} "
          f"{'cache hit %':>11}")
    for r in rows["reconstruct"]:
        c = r["cache"] or {"hits": 0, "misses": 1}
        print(f"{r['views']:>6} {r['seconds']:>8.1f} {r['depth_s']:>8.1f} {r['depth_s'] / r['views']:>7.2f} "
              f"{r['fusion_s']:>8.1f} {r['peak_rss_mb']:>11.0f} {100 * c['hits'] / (c['hits'] + c['misses']):>11.0f}")
    print(f"\nfuse (normal, depth maps {a.fuse_size})")
    print(f"{'views':>6} {'Mpix':>6} {f'{a.memory_gb} GB s':>10} {'peak RSS MB':>11} {'default s':>9} "
          f"{'peak RSS MB':>11}")
    for r in rows["fuse"]:
        print(f"{r['views']:>6} {r['megapixels']:>6.0f} {r['budget_s']:>10.1f} {r['budget_rss_mb']:>11.0f} "
              f"{r['default_s']:>9.1f} {r['default_rss_mb']:>11.0f}")
    print(f"\n1 vs 2 processes ({a.ranks_views} views, reconstruct as above)")
    for r in rows["ranks"]:
        print(f"{r['processes']} process(es) x {r['threads']} thread(s): {r['seconds']:.1f} s, peak RSS "
              f"{r['peak_rss_mb_per_process']:.0f} MB per process")
    if a.json:
        from mvsformerpp.utils.atomic import atomic_write_text

        atomic_write_text(Path(a.json), json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
