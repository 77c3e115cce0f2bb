"""Looking at results: error-coloured PLY clouds (no extra needed) and plots (``plot`` extra, matplotlib)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.io.ply import write_ply
from mvsformerpp.utils.atomic import atomic_open
from mvsformerpp.utils.file_kinds import ERROR_CLOUD, PLOT_FORMATS, PLOT_MARKER, plot_kind
from mvsformerpp.utils.output_guard import claim_output_file

# Colour ramp for errors, blue (0) -> cyan -> green -> yellow -> red (>= max): anchors at equal steps.
_RAMP = np.array([[0, 0, 255], [0, 255, 255], [0, 255, 0], [255, 255, 0], [255, 0, 0]], dtype=np.float64)


def error_colors(distances: np.ndarray, max_dist: float) -> np.ndarray:
    """[N] distances -> [N,3] uint8 colours; 0 is blue, ``max_dist`` and beyond are red."""
    x = np.clip(np.asarray(distances, dtype=np.float64) / max_dist, 0.0, 1.0) * (len(_RAMP) - 1)
    lo = np.minimum(np.floor(x).astype(np.int64), len(_RAMP) - 2)
    w = (x - lo)[:, None]
    return np.round(_RAMP[lo] * (1 - w) + _RAMP[lo + 1] * w).astype(np.uint8)


def write_error_ply(path: str | Path, points: np.ndarray, distances: np.ndarray, max_dist: float,
                    inputs: Sequence[str | Path] = ()) -> None:
    """Write points coloured by their error, with the error itself as a float property ``error``; ``path`` is
    new or an error cloud this package wrote, and none of ``inputs`` (:mod:`mvsformerpp.utils.output_guard`)."""
    points, distances = np.asarray(points), np.asarray(distances)
    if len(points) != len(distances):
        raise ValueError(f"{len(points)} points but {len(distances)} distances")
    with claim_output_file(path, ERROR_CLOUD, inputs, "--error-ply"):
        write_ply(path, points, rgb=error_colors(distances, max_dist), extra={"error": distances.astype(np.float32)},
                  kind=ERROR_CLOUD)


def _pyplot():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as e:
        raise MissingDependencyError("matplotlib", "plot", "Plotting evaluation results") from e
    return plt


def plot_format(path: str | Path) -> str:
    """The format of a plot file by its suffix (png without one); InputError for a format with no creator field
    to mark it by (:data:`~mvsformerpp.utils.file_kinds.PLOT_FORMATS`)."""
    suffix = Path(path).suffix.lstrip(".").lower() or "png"
    if suffix not in PLOT_FORMATS:
        raise InputError(f"--plot {path}: cannot write a .{suffix} plot; name it .{', .'.join(PLOT_FORMATS)}")
    return suffix


def _save(fig, path: str | Path) -> None:
    fmt = plot_format(path)
    if fmt in ("jpg", "jpeg"):  # (JPEG: a comment; the others: the creator in their metadata)
        marked = {"pil_kwargs": {"comment": PLOT_MARKER.encode()}}
    else:
        marked = {"metadata": {"Software" if fmt == "png" else "Creator": PLOT_MARKER}}
    with claim_output_file(path, plot_kind(fmt), flag="--plot"), atomic_open(path, "wb") as f:
        fig.savefig(f, format=fmt, dpi=120, bbox_inches="tight", **marked)


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
