"""Can an edge-aware, confidence-weighted smoothing of the depth maps fix what the network gets wrong?

Hypothesis: pixels with nothing to match (painted walls) are wrong because they carry little evidence, so
their depth should come from the confident pixels around them, as far as the image shows no edge. Each
depth map of ``reconstruct`` (shipped weights unless ``--checkpoint``) is replaced by the inverse depth x
that minimises

    sum_i c_i^p (x_i - 1/d_i)^2 + lam * sum_(i,j neighbours) exp(-(I_i - I_j)^2 / (2 sigma^2)) (x_i - x_j)^2

(c: the network's confidence, I: the reference photo's grey level in 0..255; a plane's inverse depth is
linear in the image, so the smoothness term leaves planes as they are), solved with preconditioned
conjugate gradients. Sets: the quality check's synthetic rooms at 640x480 as drawn and with painted walls,
and its training-style windows and held-out style at 192x256 (4 scenes of 5 views each, held-out seeds).
Per set and setting: the share of valid pixels within 10 % of the true depth and within 1 % of the
depth range.

    PYTHONPATH=src python bench/confidence_smoothing.py [--out DIR] [--checkpoint PATH]
        [--settings 10,4,2 100,4,2 ...] [--json PATH]

``--out`` keeps the scenes and reconstructions; a second run with the same folder reuses them.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np


def smooth_inverse_depth(depth: np.ndarray, conf: np.ndarray, gray: np.ndarray, lam: float, sigma: float,
                         power: float) -> np.ndarray:
    """The minimiser of the module docstring's energy, as depth."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    H, W = depth.shape
    inv = 1.0 / depth.astype(np.float64)
    scale = inv.mean()
    data = np.maximum(conf.astype(np.float64), 1e-4).ravel() ** power
    index = np.arange(H * W).reshape(H, W)
    rows, cols, vals = [], [], []
    for dy, dx in ((0, 1), (1, 0)):
        a, b = index[:H - dy, :W - dx].ravel(), index[dy:, dx:].ravel()
        g = (gray[:H - dy, :W - dx] - gray[dy:, dx:]).ravel().astype(np.float64)
        w = lam * np.exp(-g * g / (2 * sigma * sigma))
        rows += [a, b]
        cols += [b, a]
        vals += [-w, -w]
    off = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(H * W, H * W))
    diag = data - np.asarray(off.sum(1)).ravel()
    x, _ = spl.cg(off + sp.diags(diag), data * inv.ravel() / scale, x0=inv.ravel() / scale, rtol=1e-5,
                  maxiter=2000, M=sp.diags(1.0 / diag))
    return (1.0 / (scale * x)).reshape(H, W).astype(np.float32)


def main() -> None:
    from model_quality import WINDOWS, synthetic_quality  # bench/ is on the path when a bench script runs
    from PIL import Image

    from mvsformerpp.io.mvsnet import read_cam
    from mvsformerpp.io.pfm import read_pfm
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig
    from mvsformerpp.utils.atomic import atomic_write_text

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, help="work folder (default: a temporary one)")
    p.add_argument("--checkpoint", help="lite weights (default: the shipped ones)")
    p.add_argument("--settings", nargs="+", default=["10,4,2", "100,4,2", "100,12,2"],
                   help="smoothings as LAM,SIGMA,POWER (default: 10,4,2 100,4,2 100,12,2)")
    p.add_argument("--json", type=Path, help="also write the table here")
    args = p.parse_args()
    sets = {  # name: synthetic_quality's arguments
        "rooms, painted walls": dict(style="train", layout="room", plain_walls=1.0, height=480, width=640),
        "rooms as drawn": dict(style="train", layout="room", height=480, width=640),
        "training style, windows": dict(style="train", sensor_width=WINDOWS),
        "held-out style": dict(style="heldout"),
    }
    settings = [None] + [tuple(float(v) for v in s.split(",")) for s in args.settings]
    config = ReconstructConfig(preset="lite", checkpoint=args.checkpoint, num_views=5, fusion="normal")
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        for name, kwargs in sets.items():
            folder = out / name.replace(" ", "_").replace(",", "")
            if not (folder / "recon_3" / "summary.json").is_file():
                synthetic_quality(folder, config, scenes=4, **kwargs)
            maps = []
            for k in range(4):
                scene, rec = folder / f"scene_{k}", folder / f"recon_{k}"
                for i in range(5):
                    photo = next((scene / "images").glob(f"{i:08d}.*"))
                    cam = read_cam(scene / "cams" / f"{i:08d}_cam.txt")
                    maps.append((np.asarray(Image.open(photo).convert("L"), np.float32),
                                 read_pfm(scene / "depth_gt" / f"{i:08d}.pfm"),
                                 read_pfm(rec / "depth_est" / f"{i:08d}.pfm"),
                                 read_pfm(rec / "confidence" / f"{i:08d}.pfm"), cam.depth_max - cam.depth_min))
            for setting in settings:
                within10 = within1 = total = 0
                for gray, gt, est, conf, depth_range in maps:
                    d = est if setting is None else smooth_inverse_depth(est, conf, gray, *setting)
                    valid = gt > 0
                    err = np.abs(d[valid] - gt[valid])
                    within10 += int((err < 0.1 * gt[valid]).sum())
                    within1 += int((err < 0.01 * depth_range).sum())
                    total += int(valid.sum())
                key = "none" if setting is None else ",".join(f"{v:g}" for v in setting)
                results.setdefault(key, {})[name] = {"within_10pct_depth": within10 / total,
                                                     "within_1pct_range": within1 / total}
                print(f"{name:25s} smoothing {key:10s} within 10 % of the depth {100 * within10 / total:5.1f} %   "
                      f"within 1 % of the range {100 * within1 / total:5.1f} %", flush=True)
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
