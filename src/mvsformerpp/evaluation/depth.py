"""Depth-map metrics: mean absolute error, share of pixels under error thresholds, AbsRel, inlier ratio."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError
from mvsformerpp.io.images import read_image
from mvsformerpp.io.pfm import read_pfm

DTU_THRESHOLDS = (2.0, 4.0, 8.0)  # mm


def depth_metrics(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None,
                  thresholds=DTU_THRESHOLDS, interval: float | None = None, inlier_rel: float = 0.01) -> dict:
    """Metrics over valid pixels (GT > 0 and finite, prediction finite, ``mask`` if given).

    ``thresholds`` are absolute (scene units), or in depth intervals when ``interval`` is given (the
    BlendedMVS convention: 1 and 3 intervals). Keys: ``mae``, ``abs_rel``, ``inlier`` (share with
    relative error < ``inlier_rel``), ``<T`` for each threshold (shares in [0, 1]), ``valid`` (count).
    A prediction of 0 (no estimate) counts as an error of the full GT depth.
    """
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    if pred.shape != gt.shape:
        raise InputError(
            f"prediction ({pred.shape[1]}x{pred.shape[0]}) and ground truth "
            f"({gt.shape[1]}x{gt.shape[0]}) differ in size"
        )
    valid = np.isfinite(gt) & (gt > 0)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    p = np.where(np.isfinite(pred), pred, 0.0)[valid]
    g = gt[valid]
    err = np.abs(p - g)
    out = {"valid": int(valid.sum())}
    if not len(g):
        return out | {"mae": float("nan"), "abs_rel": float("nan"), "inlier": float("nan")}
    out["mae"] = float(err.mean())
    out["abs_rel"] = float((err / g).mean())
    out["inlier"] = float((err / g < inlier_rel).mean())
    scale = interval if interval else 1.0
    for t in thresholds:
        out[f"<{t:g}"] = float((err < t * scale).mean())
    return out


def _read_depth(path: Path) -> np.ndarray:
    if path.suffix == ".pfm":
        d = read_pfm(path)
        return d if d.ndim == 2 else d[..., 0]
    if path.suffix == ".npy":
        return np.load(path)
    raise InputError("depth maps must be .pfm or .npy", path)


def evaluate_depth_folders(pred_dir: str | Path, gt_dir: str | Path, mask_dir: str | Path | None = None,
                           thresholds=DTU_THRESHOLDS, interval: float | None = None) -> dict:
    """Per-view and aggregated (pixel-weighted) metrics for depth maps matched by file stem."""
    pred_dir, gt_dir = Path(pred_dir), Path(gt_dir)
    for d in (pred_dir, gt_dir):
        if not d.is_dir():
            raise InputError("not a folder", d)
    gts = {p.stem: p for p in sorted(gt_dir.iterdir()) if p.suffix in (".pfm", ".npy")}
    preds = {p.stem: p for p in sorted(pred_dir.iterdir()) if p.suffix in (".pfm", ".npy")}
    common = sorted(set(gts) & set(preds))
    if not common:
        raise InputError(f"no depth map names in common (ground truth has {len(gts)}, prediction {len(preds)})",
                         pred_dir)
    per_view, sums, total = {}, {}, 0
    for stem in common:
        pred, gt = _read_depth(preds[stem]), _read_depth(gts[stem])
        mask = None
        if mask_dir is not None:
            mpath = next((p for p in Path(mask_dir).glob(f"{stem}.*")), None)
            if mpath is None:
                raise InputError(f"no mask for {stem}", mask_dir)
            mask = read_image(mpath)[..., 0] > 127
        if pred.shape != gt.shape:
            raise InputError(f"{stem}: prediction {pred.shape[::-1]} and ground truth {gt.shape[::-1]} differ in size",
                             preds[stem])
        m = depth_metrics(pred, gt, mask, thresholds, interval)
        per_view[stem] = m
        n = m["valid"]
        total += n
        for k, v in m.items():
            if k != "valid" and n:
                sums[k] = sums.get(k, 0.0) + v * n
    overall = {k: v / total for k, v in sums.items()} | {"valid": total, "views": len(common)}
    return {"overall": overall, "per_view": per_view, "missing_predictions": sorted(set(gts) - set(preds))}
