"""Geometry alone: a textured plane with exact depth, seen sideways, verging and tilted, at several sizes.

Each case is :func:`mvsformerpp.synth.planes.plane_scene` (5 cameras in a row, the plane's centre moving by
width / 32 pixels between neighbours, so every size sees the same angles), reconstructed as a user runs
``reconstruct`` (the ``lite`` network, the shipped weights unless ``--checkpoint``); the reference view's
depth is compared with the truth on its central region (an eighth of each side left out). Per case:

* ``bias``: the median of (depth - truth) / truth (a systematic error in the matching);
* ``within_1pct``: the share of pixels within 1 % of the true depth;
* ``mean_abs_rel``: the mean |depth - truth| / truth;
* ``stage1_shift``: the image shift between stage 1's neighbouring planes in the cam files' depth range,
  in stage-1 pixels summed over the source views (:func:`mvsformerpp.inference.search_range.stage1_shift`;
  the range is the views' depths widened by a quarter, as tight as a range from sparse points: ``reconstruct
  --min-parallax`` widens what stage 1 searches where this is small);
* ``slope`` (tilted planes): the least-squares slope of the estimated inverse depth against the true one
  over the region: 1 keeps the plane's slant, below 1 flattens it towards a fronto-parallel plane.

    PYTHONPATH=src python bench/plane_check.py [--sizes 192x256 480x640] [--cases slide verge tilt30 tilt60]
                                               [--views 2..5] [--min-parallax PX] [--checkpoint PATH]
                                               [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import re
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = {"slide": dict(tilt_deg=0.0, verge=False), "verge": dict(tilt_deg=0.0, verge=True),
         "tilt30": dict(tilt_deg=30.0, verge=False), "tilt60": dict(tilt_deg=60.0, verge=False)}


def size_arg(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text)
    if not m or min(int(m[1]), int(m[2])) < 32:
        raise argparse.ArgumentTypeError(f"a size is HEIGHTxWIDTH with both at least 32, got {text!r}")
    return int(m[1]), int(m[2])


def depth_scores(est: np.ndarray, truth: np.ndarray, margin: int = 8) -> dict:
    """The module docstring's measures on the central region (1 / ``margin`` of each side left out)."""
    H, W = truth.shape
    region = (slice(H // margin, H - H // margin), slice(W // margin, W - W // margin))
    e, t = est[region].astype(np.float64), truth[region].astype(np.float64)
    ok = e > 0
    rel = (e[ok] - t[ok]) / t[ok]
    inv_t, inv_e = 1.0 / t[ok], 1.0 / e[ok]
    spread = inv_t - inv_t.mean()
    slope = float(spread @ (inv_e - inv_e.mean()) / (spread @ spread)) if np.ptp(inv_t) > 1e-3 * inv_t.mean() else None
    return {"bias": float(np.median(rel)), "within_1pct": float(np.mean(np.abs(rel) < 0.01)),
            "mean_abs_rel": float(np.mean(np.abs(rel))), "slope": slope, "coverage": float(ok.mean())}


def check_case(out_dir: Path, height: int, width: int, case: str, checkpoint: str | None = None,
               views: int = 5, min_parallax: float | None = None) -> dict:
    """Render, reconstruct and score one case (:data:`CASES`) with ``views`` views per depth map (the nearest
    cameras) and ``reconstruct --min-parallax`` (None: its default)."""
    from mvsformerpp.inference.search_range import stage1_shift
    from mvsformerpp.io.pfm import read_pfm
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct
    from mvsformerpp.synth.planes import plane_scene, write_plane_scene

    scene = plane_scene(height, width, **CASES[case])
    folder = write_plane_scene(out_dir / "scene", scene)
    sources = [(scene.K, scene.extrinsics[j]) for j in range(1, views)]  # the nearest cameras come first
    shift = stage1_shift(scene.K, scene.extrinsics[0], sources, *scene.depth_range, width, height)
    cfg = ReconstructConfig(preset="lite", checkpoint=checkpoint, num_views=views, fusion="none",
                            max_size=max(height, width), output_resolution="original", min_parallax=min_parallax)
    t = time.perf_counter()
    reconstruct(folder, out_dir / "recon", cfg, quiet=True)
    est = read_pfm(out_dir / "recon" / "depth_est" / "00000000.pfm")
    return {"case": case, "size": [height, width], "views": views, "stage1_shift": shift,
            **depth_scores(est, scene.depth), "seconds": time.perf_counter() - t}


def main() -> None:
    from mvsformerpp.utils.allocator import tune_allocator

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", nargs="+", type=size_arg, default=[(192, 256), (480, 640)], metavar="HxW")
    p.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    p.add_argument("--views", type=int, choices=range(2, 6), default=5, metavar="2..5",
                   help="views per depth map (default 5; 2: the reference and its nearest camera)")
    p.add_argument("--min-parallax", type=float, metavar="PX",
                   help="reconstruct's --min-parallax (default: its own); 0 searches the cam files' ranges as given")
    p.add_argument("--checkpoint", help="lite weights (default: the shipped ones)")
    p.add_argument("--json", help="also write the rows here")
    args = p.parse_args()
    tune_allocator()
    rows = []
    print(f"{'size':>9s} {'case':7s} {'shift':>6s} {'bias':>8s} {'within 1 %':>10s} {'mean |rel|':>10s} {'slope':>6s}")
    with tempfile.TemporaryDirectory() as tmp:
        for h, w in args.sizes:
            for case in args.cases:
                r = check_case(Path(tmp) / f"{case}_{h}x{w}", h, w, case, args.checkpoint, args.views,
                               args.min_parallax)
                rows.append(r)
                slope = "" if r["slope"] is None else f"{r['slope']:.3f}"
                print(f"{h:>4d}x{w:<4d} {case:7s} {r['stage1_shift']:6.3f} {100 * r['bias']:+7.2f}% "
                      f"{100 * r['within_1pct']:9.1f}% "
                      f"{100 * r['mean_abs_rel']:9.2f}% {slope:>6s}", flush=True)
    if args.json:
        from mvsformerpp.models.weights import weights_for
        from mvsformerpp.utils.atomic import atomic_write_text

        weights = weights_for("lite", args.checkpoint).description
        atomic_write_text(args.json, json.dumps({"weights": weights, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
