"""Eval-forward time and peak memory of the paper network (5 views): our two paths beside the official
code, with a profile of where the time goes.

Paths (each in a fresh subprocess, so peak RSS is clean, alternated over ``--repeats`` rounds):

* ``prepared``: ``model.prepare_for_inference()``, what the ``mvsformerpp`` commands run;
* ``plain``: ``model.eval()`` under ``torch.no_grad()``, what a PyTorch user calls first;
* ``official``: the official code (maybeLx/MVSFormerPlusPlus) from a checkout given with
  ``--official DIR`` (never vendored or downloaded here), built on the CPU with the same weights
  (one random state_dict, written once and loaded by every path) and the same inputs; its depth maps
  are compared with ours, so the run also shows that the speed costs no parity.

``first s`` is the first forward after building the model, ``time s`` the next one (steady state, as
when a scene is reconstructed view after view); ratios use the best round of each. The floor is the
forward's FLOPs (torch.utils.flop_counter) divided by this machine's sgemm rate, both measured here.
Every path runs with the malloc tuning the ``mvsformerpp`` command applies
(mvsformerpp.utils.allocator) unless ``--system-allocator``.

    python bench/bench_model.py [--sizes 512x640 1152x1536] [--paths prepared plain official]
        [--official DIR] [--precision fp32|bf16] [--repeats 2] [--json PATH]
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

# The official code measured on a 2-core machine of this kind (fp32), used when no checkout is given.
OFFICIAL = {"512x640": (11.0, 2.0), "1152x1536": (70.0, 5.0)}  # seconds, GB
PARTS = ["vit", "decoder_vit", "encoder", "decoder", "FMT_module", "fusions.0.cost_reg", "fusions.0",
         "fusions.1", "fusions.2", "fusions.3"]
ENTRY_POINTS = ("forward", "forward_taps", "forward_interval_features", "cost_volume", "predict")
PART_NAMES = {"vit": "DINOv2", "decoder_vit": "SVA", "encoder": "FPN enc", "decoder": "FPN dec",
              "FMT_module": "FMT", "fusions.0.cost_reg": "CVT", "fusions.0": "stage 1 rest",
              "fusions.1": "stage 2", "fusions.2": "stage 3", "fusions.3": "stage 4"}


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


def synthetic_inputs(H: int, W: int, views: int, device: str, depth_planes: int = 2):
    """Random images, cameras on a line 50 units apart (DTU-like depth range 425-935): the forward's
    inputs. ``depth_planes`` > 2 lists that many depths (the official loaders' form; both models read
    only the first and the last)."""
    import torch

    g = torch.Generator().manual_seed(0)
    imgs = torch.randn(1, views, 3, H, W, generator=g).to(device)
    proj = {}
    for s, f in enumerate((8, 4, 2, 1)):
        P = torch.zeros(1, views, 2, 4, 4, device=device)
        P[:, :, 0] = torch.eye(4)
        P[:, :, 0, 0, 3] = torch.arange(views) * 50.0
        P[:, :, 1, :3, :3] = torch.tensor([[1.2 * W / f, 0, W / 2 / f], [0, 1.2 * W / f, H / 2 / f], [0, 0, 1]])
        proj[f"stage{s + 1}"] = P
    return imgs, proj, torch.linspace(425.0, 935.0, depth_planes, device=device)[None]


def official_model(checkout: str):
    """The official network built from a checkout (its DINOv2 file bypassed: weights come from the
    state_dict loaded afterwards)."""
    import copy
    import io
    import warnings
    from contextlib import redirect_stdout

    warnings.filterwarnings("ignore")
    sys.path.insert(0, checkout)
    with open(os.path.join(checkout, "config", "mvsformer++.json")) as f:
        args = json.load(f)["arch"]["args"]
    args["vit_path"] = os.path.join(checkout, "does-not-exist.pth")
    try:
        from models.networks.DINOv2_mvsformer_model import DINOv2MVSNet
    except ModuleNotFoundError as e:
        raise SystemExit(f"the official code imports {e.name!r} (not installed): pip install {e.name}") from None
    with redirect_stdout(io.StringIO()):
        return DINOv2MVSNet(copy.deepcopy(args))


def child(path: str, size: str, device: str, precision: str, views: int, weights: str, checkout: str | None,
          depth_out: str, count_flops: bool, tune: bool) -> dict:
    import resource

    if tune:
        from mvsformerpp.utils.allocator import tune_allocator

        tune_allocator()
    import numpy as np
    import torch

    H, W = (int(x) for x in size.split("x"))
    state = torch.load(weights, map_location="cpu", mmap=True, weights_only=True)
    if path == "official":
        model = official_model(checkout)
        model.load_state_dict({k: v for k, v in state.items() if k in model.state_dict()}, strict=False)
        missing = set(model.state_dict()) - set(state)
        if any("pe_dict" not in k for k in missing):
            raise SystemExit(f"the official model has keys the state_dict lacks: {sorted(missing)[:5]}")
        model.eval()
    else:
        from mvsformerpp.models import build_model

        model = build_model("paper")
        model.load_state_dict(state)
        model.eval()
        if path == "prepared":
            model.prepare_for_inference()
    del state
    model.to(device)
    imgs, proj, dv = synthetic_inputs(H, W, views, device, depth_planes=192 if path == "official" else 2)
    dtype = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}[precision]
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    parts = dict.fromkeys(PARTS, 0.0)
    nesting = dict.fromkeys(PARTS, 0)

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    def timed(name, fn):
        def wrapper(*args, **kwargs):
            nesting[name] += 1
            if nesting[name] == 1:
                sync()
                t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                nesting[name] -= 1
                if nesting[name] == 0:
                    sync()
                    parts[name] += time.perf_counter() - t0
        return wrapper

    # Each part's entry points, whichever of them the model calls (both models call some parts by a
    # method other than forward); nested calls of one part count once.
    for name in PARTS:
        m = model.get_submodule(name)
        for method in ENTRY_POINTS:
            if hasattr(type(m), method):
                setattr(m, method, timed(name, getattr(m, method)))

    def run():
        kwargs = {"tmp": [5.0, 5.0, 5.0, 1.0]} if path == "official" else {}
        with torch.no_grad(), torch.autocast(device, dtype=dtype or torch.float32, enabled=dtype is not None):
            out = model(imgs, proj, dv, **kwargs)
        sync()
        return out

    if device == "cuda":
        run()
        torch.cuda.reset_peak_memory_stats()
    t = time.perf_counter()
    out = run()
    cold = time.perf_counter() - t
    depth = out["refined_depth"] if "refined_depth" in out else out["depth"]
    np.save(depth_out, depth.float().cpu().numpy())
    del out, depth
    parts.update(dict.fromkeys(PARTS, 0.0))
    t = time.perf_counter()
    run()
    seconds = time.perf_counter() - t
    steady = dict(parts)
    steady["fusions.0"] -= steady["fusions.0.cost_reg"]
    res = {"path": path, "size": size, "device": device, "precision": precision, "seconds": seconds,
           "cold_seconds": cold, "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
           "rss_after_build_gb": rss0 / 1e6, "parts": steady}
    if device == "cuda":
        res["peak_cuda_gb"] = torch.cuda.max_memory_allocated() / 1e9
    if count_flops:
        from torch.utils.flop_counter import FlopCounterMode

        with FlopCounterMode(display=False) as fc:
            run()
        res["gflop"] = fc.get_total_flops() / 1e9
    return res


def write_weights(path: str) -> None:
    """One random state_dict of the paper network (seed 0) for every path to load."""
    import torch

    from mvsformerpp.models import build_model

    torch.manual_seed(0)
    torch.save(build_model("paper").state_dict(), path)


def depth_difference(a: str, b: str) -> float:
    """max |a - b| / max |b| of two saved depth maps."""
    import numpy as np

    x, y = np.load(a).astype(np.float64), np.load(b).astype(np.float64)
    return float(np.abs(x - y).max() / np.abs(y).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", default=["512x640", "1152x1536"])
    ap.add_argument("--paths", nargs="+", choices=["prepared", "plain", "official"])
    ap.add_argument("--official", metavar="DIR", help="a checkout of maybeLx/MVSFormerPlusPlus to time beside ours")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--precision", default="fp32", choices=["fp32", "bf16", "fp16"])
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=1, help="rounds of all paths, alternated (best round counts)")
    ap.add_argument("--no-flops", action="store_true", help="skip FLOP counting (it costs one more forward)")
    ap.add_argument("--system-allocator", action="store_true", help="glibc's default malloc settings")
    ap.add_argument("--json", metavar="PATH", help="also write every measurement here")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        path, size, weights, depth_out, checkout = a.child
        print(json.dumps(child(path, size, a.device, a.precision, a.views, weights, checkout or None, depth_out,
                               not a.no_flops and path != "official", not a.system_allocator)))
        return
    paths = a.paths or (["prepared", "plain", "official"] if a.official else ["prepared", "plain"])
    if "official" in paths:
        if not a.official:
            ap.error("--paths official needs --official DIR (a checkout of maybeLx/MVSFormerPlusPlus)")
        if not (Path(a.official) / "models" / "networks" / "DINOv2_mvsformer_model.py").is_file():
            ap.error(f"--official {a.official}: not a checkout of maybeLx/MVSFormerPlusPlus "
                     "(models/networks/DINOv2_mvsformer_model.py is missing)")
    rate = sgemm_gflops() if a.device == "cpu" else float("nan")
    runs: dict[tuple[str, str], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        weights = os.path.join(tmp, "weights.pt")
        write_weights(weights)
        for r in range(a.repeats):
            for size in a.sizes:
                for path in paths if r % 2 == 0 else paths[::-1]:
                    cmd = [sys.executable, __file__, "--child", path, size, weights,
                           os.path.join(tmp, f"{path}-{size}.npy"),
                           os.path.abspath(a.official) if path == "official" else "",
                           "--device", a.device, "--precision", a.precision, "--views", str(a.views)]
                    cmd += ["--no-flops"] if a.no_flops or r > 0 else []  # FLOPs do not change between rounds
                    cmd += ["--system-allocator"] if a.system_allocator else []
                    out = subprocess.run(cmd, capture_output=True, text=True)
                    if out.returncode:
                        raise SystemExit(f"{path} at {size} failed:\n{out.stderr[-3000:]}")
                    runs.setdefault((size, path), []).append(json.loads(out.stdout.strip().splitlines()[-1]))
        # Each row: its fastest round, the lowest peak RSS, the first round's FLOPs, every round's time.
        rows = {}
        for key, results in runs.items():
            row = dict(min(results, key=lambda res: res["seconds"]))
            row.update(peak_rss_gb=min(res["peak_rss_gb"] for res in results),
                       rounds=[res["seconds"] for res in results])
            if "gflop" in results[0]:
                row["gflop"] = results[0]["gflop"]
            rows[key] = row
        if "official" in paths:  # the depth maps of the last round (every round computes the same ones)
            for (size, path), row in rows.items():
                if path != "official":
                    row["depth_vs_official"] = depth_difference(os.path.join(tmp, f"{path}-{size}.npy"),
                                                                os.path.join(tmp, f"official-{size}.npy"))
    if a.device == "cpu":
        rate = max(rate, sgemm_gflops())
        print(f"sgemm: {rate:.0f} GFLOP/s (cpu, best of the trials before and after the runs)")
    print("malloc: " + ("glibc defaults" if a.system_allocator else "tuned as the mvsformerpp command does"))
    print(f"{a.views} views, {a.precision}, best of {a.repeats} round(s); official: "
          + (a.official if "official" in paths else f"not run (reference numbers {OFFICIAL})"))
    hdr = (f"{'size':>10} {'path':>9} {'first s':>8} {'time s':>8} {'GFLOP':>6} {'x floor':>8} {'peak GB':>8} "
           f"{'speed-up':>9} {'memory':>7} {'depth vs official':>18}")
    print("\n" + hdr)
    for (size, path), r in rows.items():
        off = rows.get((size, "official"))
        off_s, off_gb = (off["seconds"], off["peak_rss_gb"]) if off else OFFICIAL.get(size, (float("nan"),) * 2)
        floor = r["gflop"] / rate if "gflop" in r else float("nan")
        diff = f"{r['depth_vs_official']:.1e}" if "depth_vs_official" in r else "-"
        gflop = r.get("gflop", float("nan"))
        print(f"{size:>10} {path:>9} {r['cold_seconds']:>8.2f} {r['seconds']:>8.2f} {gflop:>6.0f} "
              f"{r['seconds'] / floor:>8.2f} {r['peak_rss_gb']:>8.2f} {off_s / r['seconds']:>8.2f}x "
              f"{r['peak_rss_gb'] / off_gb:>6.2f}x {diff:>18}")
    print("\nspeed-up: official time / this path's (steady state); memory: peak RSS / the official's")
    print("\nwhere the time goes (s, steady state)")
    print(f"{'size':>10} {'path':>9} " + " ".join(f"{PART_NAMES[p]:>{max(7, len(PART_NAMES[p]))}}" for p in PARTS)
          + f" {'other':>7}")
    for (size, path), r in rows.items():
        other = r["seconds"] - sum(r["parts"].values())
        print(f"{size:>10} {path:>9} " + " ".join(f"{r['parts'][p]:>{max(7, len(PART_NAMES[p]))}.2f}" for p in PARTS)
              + f" {other:>7.2f}")
    if a.json:
        from mvsformerpp.utils.atomic import atomic_write_text

        atomic_write_text(a.json, json.dumps({"sgemm_gflops": rate, "rows": list(rows.values())}, indent=1))


if __name__ == "__main__":
    main()
