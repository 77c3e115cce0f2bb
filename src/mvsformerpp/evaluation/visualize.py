"""Looking at results: error-coloured PLY clouds (no extra needed) and plots (``plot`` extra, matplotlib)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import MissingDependencyError
from mvsformerpp.io.ply import write_ply
from mvsformerpp.utils.atomic import atomic_open
from mvsformerpp.utils.output_guard import check_replaceable

# Colour ramp for errors, blue (0) -> cyan -> green -> yellow -> red (>= max): anchors at equal steps.
_RAMP = np.array([[0, 0, 255], [0, 255, 255], [0, 255, 0], [255, 255, 0], [255, 0, 0]], dtype=np.float64)


def error_colors(distances: np.ndarray, max_dist: float) -> np.ndarray:
    """[N] distances -> [N,3] uint8 colours; 0 is blue, ``max_dist`` and beyond are red."""
    x = np.clip(np.asarray(distances, dtype=np.float64) / max_dist, 0.0, 1.0) * (len(_RAMP) - 1)
    lo = np.minimum(np.floor(x).astype(np.int64), len(_RAMP) - 2)
    w = (x - lo)[:, None]
    return np.round(_RAMP[lo] * (1 - w) + _RAMP[lo + 1] * w).astype(np.uint8)


def write_error_ply(path: str | Path, points: np.ndarray, distances: np.ndarray, max_dist: float) -> None:
    """Write points coloured by their error, with the error itself as a float property ``error``."""
    points, distances = np.asarray(points), np.asarray(distances)
    if len(points) != len(distances):
        raise ValueError(f"{len(points)} points but {len(distances)} distances")
    check_replaceable(path, (b"ply",), "PLY", "--error-ply")
    write_ply(path, points, rgb=error_colors(distances, max_dist), extra={"error": distances.astype(np.float32)})


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise MissingDependencyError("matplotlib", "plot", "Plotting evaluation results") from e
    return plt


# What a plot file of each format starts with: only such a file is replaced.
PLOT_MAGICS = {"png": (b"\x89PNG",), "pdf": (b"%PDF",), "svg": (b"<?xml", b"<svg"), "jpg": (b"\xff\xd8",),
               "jpeg": (b"\xff\xd8",), "eps": (b"%!PS",), "ps": (b"%!PS",)}


def _save(fig, path: str | Path) -> None:
    suffix = Path(path).suffix.lstrip(".").lower() or "png"
    check_replaceable(path, PLOT_MAGICS.get(suffix, (b"\x89PNG", b"%PDF", b"<?xml", b"<svg")), "plot", "--plot")
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format=suffix, dpi=120, bbox_inches="tight")


def plot_per_scan(path: str | Path, names: list[str], values: dict[str, list[float]], ylabel: str = "mm") -> None:
    """Grouped bar chart: one group per scan, one bar per metric (e.g. accuracy, completeness, overall)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(max(6, 0.5 * len(names)), 3.5))
    width = 0.8 / max(1, len(values))
    x = np.arange(len(names))
    for i, (label, v) in enumerate(values.items()):
        ax.bar(x + i * width, v, width, label=label)
    ax.set_xticks(x + 0.4 - width / 2, names, rotation=90)
    ax.set_ylabel(ylabel)
    ax.legend()
    _save(fig, path)
    plt.close(fig)


def plot_pr_curves(path: str | Path, curve: dict[str, np.ndarray], threshold: float | None = None,
                   unit: str = "") -> None:
    """Precision, recall and F-score against the distance threshold (``CloudDistances.curve`` output)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for key in ("precision", "recall", "f_score"):
        ax.plot(curve["thresholds"], curve[key] * 100, label=key)
    if threshold is not None:
        ax.axvline(threshold, color="k", linestyle="--", linewidth=0.8)
    ax.set_xlabel(f"threshold {unit}".strip())
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.legend()
    _save(fig, path)
    plt.close(fig)
