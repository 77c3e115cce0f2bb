"""Charts for evaluation reports (needs the ``plot`` extra: matplotlib)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import MissingDependencyError


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise MissingDependencyError("matplotlib", "plot", "Plotting") from e
    return plt


def _save(fig, path: str | Path) -> Path:
    from mvsformerpp.utils.atomic import atomic_open

    with atomic_open(path, "wb") as f:
        fig.savefig(f, format=Path(path).suffix.lstrip(".") or "png", dpi=120, bbox_inches="tight")
    return Path(path)


def plot_dtu_bars(results, path: str | Path) -> Path:
    """Per-scan accuracy / completeness / overall bar chart."""
    plt = _pyplot()
    scans = [str(r.scan) for r in results]
    x = np.arange(len(scans))
    fig, ax = plt.subplots(figsize=(max(6, len(scans) * 0.6), 3.5))
    for k, (name, vals) in enumerate((("accuracy", [r.accuracy for r in results]),
                                      ("completeness", [r.completeness for r in results]),
                                      ("overall", [r.overall for r in results]))):
        ax.bar(x + (k - 1) * 0.27, vals, 0.27, label=name)
    ax.set_xticks(x, scans)
    ax.set_xlabel("scan")
    ax.set_ylabel("mm (lower is better)")
    ax.legend()
    path = _save(fig, path)
    plt.close(fig)
    return path


def plot_pr_curves(d_pred: np.ndarray, d_gt: np.ndarray, max_threshold: float, path: str | Path) -> Path:
    """Precision, recall and F-score against the distance threshold."""
    from mvsformerpp.evaluation.cloud import curves

    plt = _pyplot()
    ts = np.linspace(max_threshold / 50, max_threshold, 50)
    ms = curves(d_pred, d_gt, ts)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.plot(ts, [m.precision for m in ms], label="precision")
    ax.plot(ts, [m.recall for m in ms], label="recall")
    ax.plot(ts, [m.f_score for m in ms], label="F-score")
    ax.set_xlabel("threshold")
    ax.set_ylim(0, 1)
    ax.legend()
    path = _save(fig, path)
    plt.close(fig)
    return path
