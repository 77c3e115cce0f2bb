"""What to say when fusion keeps no point: the confidences seen, and a command that does keep points."""

from __future__ import annotations

import dataclasses
import shlex
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mvsformerpp.fusion import FusionConfig
from mvsformerpp.fusion.config import METHODS
from mvsformerpp.io.masks import EMPTY_MASKS, read_mask

# Confidence values sampled per view for the percentiles (a regular subsample bounds the memory).
SAMPLES_PER_VIEW = 1 << 18


def confidence_percentiles(depth_folder) -> dict[int, float] | None:
    """10th/50th/90th percentiles of the confidence over pixels with a depth (None without any).

    ``depth_folder`` reads views one at a time (:class:`mvsformerpp.io.depth_folder.DepthFolder`).
    """
    if not depth_folder.has_confidence:
        return None
    values = []
    for i in range(len(depth_folder.scene)):
        depth, conf, _ = depth_folder.read(i)
        v = conf[depth > 0].ravel()
        values.append(v[:: max(1, len(v) // SAMPLES_PER_VIEW)])
    values = np.concatenate(values) if values else np.zeros(0)
    if values.size == 0:
        return None
    return {q: float(np.percentile(values, q)) for q in (10, 50, 90)}


def fuse_command(folder: Path, out_ply: Path, config: FusionConfig) -> str:
    """The ``mvsformerpp fuse`` command line that reproduces ``config`` (paths quoted for a POSIX shell)."""
    args = ["mvsformerpp", "fuse", str(folder), "-o", str(out_ply), "--fusion", config.method,
            "--conf", f"{config.conf_threshold:g}", "--disp", f"{config.disp_threshold:g}",
            "--num-consistent", str(config.num_consistent), "--num-src-views", str(config.num_src_views)]
    return " ".join(shell_quote(a) for a in args)


def shell_quote(arg: str) -> str:
    """``arg`` quoted for a POSIX shell, on one line: a name holding a newline or another control character
    becomes ``"$(printf '...')"`` with the character escaped, so the printed command still names that file."""
    if arg.isprintable():
        return shlex.quote(arg)
    escaped = "".join(c if c.isprintable() and c != "\\" else
                      "".join(f"\\0{b:03o}" for b in c.encode("utf-8", "surrogateescape")) for c in arg)
    return f"\"$(printf '%b' {shlex.quote(escaped)})\""


def explain_empty_cloud(depth_folder, config: FusionConfig, folder: Path, out_ply: Path,
                        count_points: Callable[[FusionConfig], int]) -> str:
    """One line: why fusion kept nothing and, where one exists, settings (tried with ``count_points``)
    that keep points."""
    if getattr(depth_folder, "mask_paths", None):

        if not any(read_mask(p).any() for p in depth_folder.mask_paths):
            return f"fusion kept no point: {EMPTY_MASKS} (--mask-dir {depth_folder.mask_paths[0].parent})"
    pct = confidence_percentiles(depth_folder)
    seen = (f"confidences of pixels with a depth: 10% {pct[10]:.3f}, median {pct[50]:.3f}, 90% {pct[90]:.3f}"
            if pct else "no confidence maps or no pixel with a depth")
    head = f"fusion ({config.method}, --conf {config.conf_threshold:g}) kept no point; {seen}"
    # Keep about half of the pixels by confidence (the filter keeps values strictly above it) and ask for
    # one consistent view, then try it.
    conf = config.conf_threshold if pct is None else max(0.0, float(np.floor((pct[50] - 1e-4) * 100) / 100))
    first = dataclasses.replace(config, conf_threshold=min(conf, config.conf_threshold), num_consistent=1)
    candidates = [first] + [dataclasses.replace(first, method=m.name) for m in METHODS.values()
                            if m.lenient and m.name != config.method]
    for cand in candidates:
        kept = count_points(cand)
        if kept:
            return f"{head}. These settings keep {kept:,} points: {fuse_command(folder, out_ply, cand)}"
    return (f"{head}; even --conf {first.conf_threshold:g} --num-consistent 1 keeps none: the depth maps "
            "disagree between views (check the cameras and the depth ranges)")
