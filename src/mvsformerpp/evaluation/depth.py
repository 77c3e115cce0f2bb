"""Depth-map metrics: MAE, threshold accuracies, AbsRel and inlier ratio; per view and aggregated.

Validity: a ground-truth pixel counts when it is finite and > 0 (and inside the optional mask).
A prediction that is 0 or non-finite at such a pixel is "missing": it is excluded from the error
averages (MAE, AbsRel) and counts as a failure for every threshold and for the inlier ratio, so a
method cannot score well by leaving pixels empty; ``coverage`` reports the share it did predict.

- ``mae``: mean |pred - gt| (depth units, mm for DTU);
- ``acc@t``: share of valid pixels with |pred - gt| < t (DTU: 2, 4, 8 mm; BlendedMVS: 1 and 3
  depth intervals, i.e. ``thresholds=(1, 3)`` with ``interval`` = the scene's depth interval);
- ``abs_rel``: mean |pred - gt| / gt;
- ``inlier``: share with max(pred/gt, gt/pred) < ``inlier_ratio`` (1.03, the robust-MVD convention).
Aggregates are pixel-weighted over all views (every valid pixel counts once).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.pfm import read_pfm

DTU_DEPTH_THRESHOLDS: tuple[float, ...] = (2.0, 4.0, 8.0)


@dataclass
class DepthSums:
    """Running sums from which every metric follows; adding two gives the metrics of both together."""

    valid: int = 0  #: valid ground-truth pixels
    predicted: int = 0  #: of those, with a valid prediction
    abs_err: float = 0.0
    rel_err: float = 0.0
    inliers: int = 0
    under: dict[float, int] = field(default_factory=dict)  #: threshold -> pixels under it

    def add(self, other: DepthSums) -> None:
        self.valid += other.valid
        self.predicted += other.predicted
        self.abs_err += other.abs_err
        self.rel_err += other.rel_err
        self.inliers += other.inliers
        for t, n in other.under.items():
            self.under[t] = self.under.get(t, 0) + n

    def metrics(self) -> dict[str, float]:
        """Metric name -> value (NaN where undefined, e.g. no valid pixel)."""
        nan = float("nan")
        out = {
            "valid_pixels": float(self.valid),
            "coverage": self.predicted / self.valid if self.valid else nan,
            "mae": self.abs_err / self.predicted if self.predicted else nan,
            "abs_rel": self.rel_err / self.predicted if self.predicted else nan,
            "inlier": self.inliers / self.valid if self.valid else nan,
        }
        for t, n in sorted(self.under.items()):
            out[f"acc@{t:g}"] = n / self.valid if self.valid else nan
        return out


def depth_sums(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None,
               thresholds: tuple[float, ...] = DTU_DEPTH_THRESHOLDS, interval: float = 1.0,
               inlier_ratio: float = 1.03) -> DepthSums:
    """Sums for one view: pred, gt [H,W]; mask [H,W] bool (True = evaluate); thresholds in units of ``interval``."""
    if pred.ndim != 2 or gt.ndim != 2:
        raise InputError(f"depth maps must have one channel, got shapes {pred.shape} (prediction), {gt.shape}")
    if pred.shape != gt.shape:
        raise InputError(f"predicted depth is {pred.shape[1]}x{pred.shape[0]} but ground truth is "
                         f"{gt.shape[1]}x{gt.shape[0]}; evaluate at the ground-truth resolution")
    valid = np.isfinite(gt) & (gt > 0)
    if mask is not None:
        if mask.shape != gt.shape:
            raise InputError(f"mask is {mask.shape[1]}x{mask.shape[0]} but ground truth is {gt.shape[1]}x{gt.shape[0]}")
        valid &= mask
    g = gt[valid].astype(np.float64)
    p = pred[valid].astype(np.float64)
    has = np.isfinite(p) & (p > 0)
    err = np.abs(p[has] - g[has])
    ratio = np.maximum(p[has] / g[has], g[has] / p[has])
    return DepthSums(
        valid=int(valid.sum()), predicted=int(has.sum()), abs_err=float(err.sum()),
        rel_err=float((err / g[has]).sum()), inliers=int((ratio < inlier_ratio).sum()),
        under={float(t): int((err < t * interval).sum()) for t in thresholds},
    )


@dataclass(frozen=True)
class DepthReport:
    """Per-view metrics (by stem) and the pixel-weighted aggregate."""

    per_view: dict[str, dict[str, float]]
    overall: dict[str, float]
    missing: list[str]  #: ground-truth stems with no prediction (counted as fully missing)


def _read_mask(path: Path, shape: tuple[int, int]) -> np.ndarray:
    if path.suffix.lower() == ".pfm":
        m = read_pfm(path)
    else:
        try:
            m = np.asarray(Image.open(path))
        except OSError as e:
            raise FormatError(f"cannot read the mask image ({e})", path) from e
    if m.ndim == 3:
        m = m[..., 0]
    if m.shape != shape:
        raise InputError(f"mask is {m.shape[1]}x{m.shape[0]}, depth is {shape[1]}x{shape[0]}", path)
    return m > 0


def _by_stem(folder: Path, suffixes: tuple[str, ...], what: str) -> dict[str, Path]:
    if not folder.is_dir():
        raise InputError(f"the {what} folder does not exist", folder)
    return {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in suffixes}


def evaluate_depth_dirs(
    pred_dir: str | Path,
    gt_dir: str | Path,
    mask_dir: str | Path | None = None,
    thresholds: tuple[float, ...] = DTU_DEPTH_THRESHOLDS,
    interval: float = 1.0,
    inlier_ratio: float = 1.03,
) -> DepthReport:
    """Compare PFM depth maps matched by file stem; GT 0 / non-finite = invalid; optional mask folder (PNG/PFM)."""
    preds = _by_stem(Path(pred_dir), (".pfm",), "predicted depth")
    gts = _by_stem(Path(gt_dir), (".pfm",), "ground-truth depth")
    masks = _by_stem(Path(mask_dir), (".png", ".pfm", ".jpg"), "mask") if mask_dir is not None else {}
    if not gts:
        raise InputError("the ground-truth folder holds no .pfm depth maps", gt_dir)
    if not set(preds) & set(gts):
        raise InputError(f"no predicted depth map shares a file name (stem) with the ground truth, e.g. "
                         f"{next(iter(gts))}.pfm", pred_dir)
    total, per_view, missing = DepthSums(), {}, []
    for stem, gt_path in gts.items():
        gt = read_pfm(gt_path)
        if gt.ndim != 2:
            raise FormatError("a depth map must have one channel", gt_path)
        mask = None
        if mask_dir is not None:
            if stem not in masks:
                raise InputError(f"no mask for view {stem}", mask_dir)
            mask = _read_mask(masks[stem], gt.shape)
        if stem in preds:
            pred = read_pfm(preds[stem])
            try:
                sums = depth_sums(pred, gt, mask, thresholds, interval, inlier_ratio)
            except InputError as e:
                raise InputError(str(e), preds[stem]) from e
        else:
            missing.append(stem)
            sums = depth_sums(np.zeros_like(gt), gt, mask, thresholds, interval, inlier_ratio)
        per_view[stem] = sums.metrics()
        total.add(sums)
    if total.valid == 0:
        if mask_dir is not None:
            raise InputError("the masks mark no pixel of any view where the ground truth has a depth, so there is "
                             "nothing to evaluate; check the masks (non-zero = evaluate) or leave out --mask-dir",
                             mask_dir)
        raise InputError("the ground truth has no valid depth (0 or non-finite everywhere) in any view", gt_dir)
    return DepthReport(per_view=per_view, overall=total.metrics(), missing=missing)


def format_depth_table(report: DepthReport) -> str:
    """One row per view plus the aggregate row."""
    keys = [k for k in report.overall if k != "valid_pixels"]
    lines = [f"{'view':>12} " + " ".join(f"{k:>9}" for k in keys)]
    for name, m in list(report.per_view.items()) + [("all", report.overall)]:
        lines.append(f"{name[:12]:>12} " + " ".join(f"{m[k]:9.4f}" for k in keys))
    return "\n".join(lines)


def grid_artifact_ratio(depth: np.ndarray, cell: int = 8, valid: np.ndarray | None = None,
                        clip: float | None = None) -> float:
    """How much a depth map steps on a ``cell``-pixel grid: the mean squared relative depth difference
    between neighbouring pixels across the grid lines (x or y a multiple of ``cell``), over the same
    mean between all other neighbours. A map without a block pattern gives about 1; a map made of
    ``cell`` x ``cell`` blocks (stage-1 cells that the fine stages did not correct) gives far more.
    The grid is counted from pixel (0, 0), where the network's cells start. ``clip``: cap every squared
    step at this percentile of all of them first (99: the largest 1 % no longer dominate). NaN without
    valid pairs."""
    depth = np.asarray(depth, dtype=np.float64)
    ok = np.isfinite(depth) & (depth > 0)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    on, off = [], []
    for axis in (0, 1):
        a, b = (depth[1:], depth[:-1]) if axis == 0 else (depth[:, 1:], depth[:, :-1])
        pair = (ok[1:] & ok[:-1]) if axis == 0 else (ok[:, 1:] & ok[:, :-1])
        rel = np.zeros_like(a)
        rel[pair] = ((a[pair] - b[pair]) / (0.5 * (a[pair] + b[pair]))) ** 2
        index = np.arange(1, depth.shape[axis])  # the pair (i - 1, i) crosses a grid line when i % cell == 0
        line = (index % cell == 0)[:, None] if axis == 0 else (index % cell == 0)[None, :]
        line = np.broadcast_to(line, rel.shape)
        on.append(rel[pair & line])
        off.append(rel[pair & ~line])
    on, off = np.concatenate(on), np.concatenate(off)
    if len(on) == 0 or len(off) == 0:
        return float("nan")
    if clip is not None:
        cap = np.percentile(np.concatenate([on, off]), clip)
        on, off = np.minimum(on, cap), np.minimum(off, cap)
    if off.mean() == 0:
        return float("nan")
    return float(on.mean() / off.mean())
