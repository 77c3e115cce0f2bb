"""Fusion throughput on a 49-view scene at 1152x1536-like sizes (synthetic depth maps).

A plane seen by 49 cameras on a 7x7 grid, analytic depth maps with 1% outliers; each method fuses
all views. ``--scale`` shrinks the images for a quick run (0.25 -> 288x384).

    python bench/bench_fusion.py [--scale 0.25] [--views 49] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from mvsformerpp.fusion import fuse_depth_maps, get_config
from mvsformerpp.io.scene import Scene, View


def plane_scene(n_views: int, H: int, W: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n_views)))
    f = 1.2 * W
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    views, depths = [], []
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    for i in range(n_views):
        c = np.array([(i % side - side / 2) * 0.15, (i // side - side / 2) * 0.15, 0.0])
        R, t = np.eye(3), -c
        # Plane z = 5 + 0.1 x (world); depth along each pixel ray, solved analytically.
        rays = np.stack([(xs - K[0, 2]) / f, (ys - K[1, 2]) / f, np.ones_like(xs)], -1)
        depth = (5 + 0.1 * c[0]) / (1 - 0.1 * rays[..., 0])
        out = rng.random(depth.shape) < 0.01
        depth[out] *= rng.uniform(0.5, 1.5, out.sum())
        depths.append(depth.astype(np.float32))
        views.append(View(f"{i:08d}", f"{i}.png", W, H, K, R, t, 3.0, 8.0))
    centers = np.stack([v.center for v in views])
    for i, v in enumerate(views):
        v.neighbors = [int(j) for j in np.argsort(np.linalg.norm(centers - centers[i], axis=1))[1:11]]
    return Scene(views), depths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--views", type=int, default=49)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--methods", nargs="+", default=["normal", "dynamic", "gipuma"])
    a = ap.parse_args()
    H, W = int(1152 * a.scale), int(1536 * a.scale)
    scene, depths = plane_scene(a.views, H, W)
    images = [np.full((H, W, 3), 128, np.uint8)] * a.views
    confs = [np.ones_like(d) for d in depths]
    pixels = a.views * H * W
    print(f"{a.views} views of {W}x{H} ({pixels / 1e6:.1f} M input pixels), {a.device}, "
          f"{torch.get_num_threads()} threads")
    print(f"{'method':>8} {'seconds':>8} {'Mpix/s':>8} {'points':>10} {'Mpts/s':>8}")
    for m in a.methods:
        cfg = get_config(m, conf_threshold=0.5)
        t = time.perf_counter()
        xyz, _ = fuse_depth_maps(scene, depths, confs, images, cfg, a.device)
        dt = time.perf_counter() - t
        print(f"{m:>8} {dt:>8.2f} {pixels / dt / 1e6:>8.2f} {len(xyz):>10,} {len(xyz) / dt / 1e6:>8.2f}")


if __name__ == "__main__":
    main()
