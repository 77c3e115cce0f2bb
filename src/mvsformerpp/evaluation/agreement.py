"""How closely two runs of a network agree on the same view: an exported model against PyTorch.

The numbers COLMAP's notes give for their ONNX export (depth difference mean and 99th percentile in
scene units, agreement of the confidence mask), plus the same in % of the depth range searched and the
relative error of the parity fixtures (largest difference over the largest value).
"""

from __future__ import annotations

import numpy as np


def depth_agreement(depth: np.ndarray, confidence: np.ndarray, ref_depth: np.ndarray, ref_confidence: np.ndarray,
                    span, conf_threshold: float) -> dict:
    """Agreement of ``depth`` / ``confidence`` with the reference run's, over the pixels where both have a
    depth (> 0, finite). Maps of any shape: several views pool as their flattened maps concatenated.

    ``span``: the depth range searched (far - near), one number or one per pixel (pooled views).
    Returns ``depth_rel_err`` (max |d - d_ref| / max |d_ref|), ``depth_diff`` and ``depth_diff_pct_of_range``
    (mean, p99, max of |d - d_ref| in scene units and of 100 |d - d_ref| / span),
    ``confidence_max_diff``, ``mask_agreement`` (share of all pixels where both confidences are on the same
    side of ``conf_threshold``, the fusion's: kept when > threshold), ``conf_threshold`` and ``pixels``.
    """
    d, r = np.asarray(depth, np.float64), np.asarray(ref_depth, np.float64)
    valid = np.isfinite(d) & np.isfinite(r) & (d > 0) & (r > 0)
    diff = np.abs(d - r)[valid]
    pct = 100.0 * diff / np.broadcast_to(np.asarray(span, np.float64), d.shape)[valid]
    c, cr = np.asarray(confidence, np.float64), np.asarray(ref_confidence, np.float64)
    return {
        "depth_rel_err": float(diff.max() / np.abs(r[valid]).max()) if diff.size else float("nan"),
        "depth_diff": _stats(diff),
        "depth_diff_pct_of_range": _stats(pct),
        "confidence_max_diff": float(np.abs(c - cr).max()),
        "mask_agreement": float(np.mean((c > conf_threshold) == (cr > conf_threshold))),
        "conf_threshold": float(conf_threshold),
        "pixels": int(valid.sum()),
    }


def _stats(x: np.ndarray) -> dict:
    if not x.size:
        return {"mean": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {"mean": float(x.mean()), "p99": float(np.percentile(x, 99)), "max": float(x.max())}
