"""Where the block pattern of the depth maps comes from: the measures of the model card's "Block pattern".

On a synthetic scene with exact depth (5 photos, every view the reference once, shipped weights unless
``--checkpoint``), it prints the median over the views of:

* features: the squared step between neighbouring pixels of the features each stage matches (FPN
  decoder output, then after the FMT pathway) across stage-1 cell borders (8 photo pixels) and across
  the lines of the 32-pixel grid, over the same elsewhere;
* stages: each stage's depth brought to full resolution (bilinear in inverse depth, as the cascade
  centres its windows) and its 8-pixel grid ratio (:func:`~mvsformerpp.evaluation.depth.grid_artifact_ratio`),
  beside the truth's;
* the final depth's grid ratio on 8- and 32-pixel grids (32: the stage-1 transformer's 4x4-cell token
  patches), all steps and with the largest 1 % clipped;
* per stage at its own resolution, the mean squared relative step by pixel index modulo 8.

``--cvt-shifts K`` runs stage 1's transformer over K placements of its token grid (``ModelConfig.cvt_shifts``;
default: the weights' stored setting, the ``lite`` preset's).

    PYTHONPATH=src python bench/block_pattern.py [--size 480 640] [--seed 5000000] [--cvt-shifts K] [--checkpoint PATH]
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np
import torch
import torch.nn.functional as F

from mvsformerpp.evaluation.depth import grid_artifact_ratio


def clipped_grid_ratio(d: np.ndarray, valid: np.ndarray, cell: int, clip: float) -> float:
    """grid_artifact_ratio with the steps above the ``clip`` percentile set to it."""
    return grid_artifact_ratio(d, cell, valid, clip=clip)


def modulo_profile(d: np.ndarray, period: int = 8) -> np.ndarray:
    """Mean squared relative step (largest 1 % clipped) by pixel index modulo ``period``, over the mean."""
    e, n = np.zeros(period), np.zeros(period)
    for axis in (0, 1):
        a, b = (d[1:], d[:-1]) if axis == 0 else (d[:, 1:], d[:, :-1])
        rel = ((a - b) / (0.5 * (a + b))) ** 2
        rel = np.minimum(rel, np.percentile(rel, 99))
        idx = np.arange(1, d.shape[axis]) % period
        for k in range(period):
            sel = rel[idx == k] if axis == 0 else rel[:, idx == k]
            e[k] += sel.sum()
            n[k] += sel.size
    return e / n / (e.sum() / n.sum())


def border_ratio(f: torch.Tensor, cell: int) -> float:
    """Squared feature step across ``cell``-pixel grid lines over the same elsewhere, f [C, h, w]."""
    on, off = [], []
    for axis in (1, 2):
        step = (f.double().diff(dim=axis) ** 2).sum(0)
        line = torch.arange(1, f.shape[axis]) % cell == 0
        line = (line[:, None] if axis == 1 else line[None, :]).expand_as(step)
        on.append(step[line])
        off.append(step[~line])
    return float(torch.cat(on).mean() / torch.cat(off).mean())


def to_full(depth: torch.Tensor, H: int, W: int) -> np.ndarray:
    inv = 1.0 / depth.clamp(min=1e-6)
    return (1.0 / F.interpolate(inv[None, None], (H, W), mode="bilinear", align_corners=True))[0, 0].double().numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, nargs=2, default=(480, 640), metavar=("H", "W"))
    ap.add_argument("--seed", type=int, default=5_000_000)
    ap.add_argument("--checkpoint", help="weights to measure (default: the shipped ones)")
    ap.add_argument("--cvt-shifts", type=int, metavar="K", help="placements of stage 1's token grid (1-4)")
    a = ap.parse_args()
    import mvsformerpp.models.mvsformer as network
    from mvsformerpp.io.images import read_image
    from mvsformerpp.io.mvsnet import read_cam
    from mvsformerpp.io.pfm import read_pfm
    from mvsformerpp.models.checkpoint import load_model
    from mvsformerpp.models.inputs import normalize, stage_projections
    from mvsformerpp.models.shipped import load_shipped
    from mvsformerpp.synth import generate_scene

    model = (load_model(a.checkpoint) if a.checkpoint else load_shipped()).prepare_for_inference()
    stage1 = model.fusions[0].cost_reg
    if a.cvt_shifts is not None:
        stage1.shifts = a.cvt_shifts
    captured = {}
    decode = network.decode_views

    def spy_decode(*args, **kwargs):
        out = decode(*args, **kwargs)
        captured["FPN decoder"] = [f[0, 0].clone() for f in out]
        return out

    fmt = model.FMT_module.forward

    def spy_fmt(features):
        out = fmt(features)
        captured["after FMT"] = [f[0, 0].clone() for f in out]
        return out

    network.decode_views, model.FMT_module.forward = spy_decode, spy_fmt
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        scene = generate_scene(tmp, seed=a.seed, num_views=5, height=a.size[0], width=a.size[1])
        cams = [read_cam(scene / "cams" / f"{i:08d}_cam.txt") for i in range(5)]
        imgs = [torch.from_numpy(read_image(scene / "images" / f"{i:08d}.png").astype(np.float32) / 255)
                .permute(2, 0, 1) for i in range(5)]
        for ref in range(5):
            order = [ref] + [i for i in range(5) if i != ref]
            proj = stage_projections(np.stack([cams[i].extrinsic for i in order]), np.stack([cams[i].K for i in order]))
            dv = torch.tensor([[cams[ref].depth_min, cams[ref].depth_max]], dtype=torch.float32)
            with torch.no_grad():
                out = model(normalize(torch.stack([imgs[i] for i in order]))[None], proj, dv)
            gt = read_pfm(scene / "depth_gt" / f"{ref:08d}.pfm").astype(np.float64)
            valid, (H, W) = gt > 0, gt.shape
            final = out["depth"][0].double().numpy()
            r = {f"features, {k}, stage {s + 1}, cell lines": border_ratio(f[s], 2 ** s)
                 for k, f in captured.items() for s in range(1, 4)}
            r |= {f"features, {k}, stage {s + 1}, 32-px lines": border_ratio(f[s], 4 * 2 ** s)
                  for k, f in captured.items() for s in range(4)}
            r |= {f"stage {s} at full resolution, 8-px grid": grid_artifact_ratio(
                to_full(out[f"stage{s}"]["depth"][0], H, W), 8, valid) for s in range(1, 5)}
            r["truth, 8-px grid"] = grid_artifact_ratio(gt, 8, valid)
            for cell in (8, 32):
                r[f"final, {cell}-px grid"] = grid_artifact_ratio(final, cell, valid)
                r[f"final, {cell}-px grid, largest 1 % clipped"] = clipped_grid_ratio(final, valid, cell, 99)
            r["final, within 1 % of the range"] = float(np.mean(np.abs(final - gt)[valid] < 0.01 * np.ptp(gt[valid])))
            r |= {f"stage {s} profile": modulo_profile(out[f"stage{s}"]["depth"][0].double().numpy())
                  for s in range(1, 5)}
            rows.append(r)
    print(f"scene seed {a.seed}, {a.size[1]}x{a.size[0]}, 5 views, stage 1 in {stage1.shifts} placement(s); "
          "medians over the views")
    for k in rows[0]:
        if k.endswith("profile"):
            print(f"  {k}: step by index mod 8 at its own resolution", np.round(np.median([r[k] for r in rows], 0), 2))
        else:
            print(f"  {k:48s} {np.median([r[k] for r in rows]):6.3f}")


if __name__ == "__main__":
    main()
