"""What to say when fusion keeps no point: the confidences seen, and a command that does keep points."""

from __future__ import annotations

import dataclasses
import shlex
from pathlib import Path

import numpy as np

from mvsformerpp.fusion import FusionConfig, fuse_depth_maps


def confidence_percentiles(depths, confs) -> dict[int, float] | None:
    """10th/50th/90th percentiles of the confidence over pixels with a depth (None without confidences)."""
    if confs is None:
        return None
    values = np.concatenate([c[d > 0].ravel() for d, c in zip(depths, confs)]) if depths else np.zeros(0)
    if values.size == 0:
        return None
    return {q: float(np.percentile(values, q)) for q in (10, 50, 90)}


def fuse_command(folder: Path, out_ply: Path, config: FusionConfig) -> str:
    """The ``mvsformerpp fuse`` command line that reproduces ``config`` (paths quoted for a POSIX shell)."""
    args = ["mvsformerpp", "fuse", str(folder), "-o", str(out_ply), "--fusion", config.method,
            "--conf", f"{config.conf_threshold:g}", "--disp", f"{config.disp_threshold:g}",
            "--num-consistent", str(config.num_consistent), "--num-src-views", str(config.num_src_views)]
    return shlex.join(args)


def explain_empty_cloud(scene, depths, confs, images, config: FusionConfig, folder: Path, out_ply: Path,
                        device: str = "cpu") -> str:
    """One line: why fusion kept nothing and, where one exists, settings (tried here) that keep points."""
    pct = confidence_percentiles(depths, confs)
    seen = (f"confidences of pixels with a depth: 10% {pct[10]:.3f}, median {pct[50]:.3f}, 90% {pct[90]:.3f}"
            if pct else "no pixel has a depth")
    head = f"fusion ({config.method}, --conf {config.conf_threshold:g}) kept no point; {seen}"
    if pct is None:
        return head + "; the depth maps are empty, so fusion cannot keep any point"
    # Keep about half of the pixels by confidence (the filter keeps values strictly above it) and ask for
    # one consistent view, then try it.
    conf = max(0.0, float(np.floor((pct[50] - 1e-4) * 100) / 100))
    candidates = [dataclasses.replace(config, conf_threshold=min(conf, config.conf_threshold), num_consistent=1)]
    if config.method != "dynamic":
        candidates.append(dataclasses.replace(candidates[0], method="dynamic"))
    for cand in candidates:
        xyz, _ = fuse_depth_maps(scene, depths, confs, images, cand, device)
        if len(xyz):
            return (f"{head}. These settings keep {len(xyz):,} points: {fuse_command(folder, out_ply, cand)}")
    return (f"{head}; even --conf {candidates[0].conf_threshold:g} --num-consistent 1 keeps none: the depth maps "
            "disagree between views (check the cameras and the depth ranges)")
