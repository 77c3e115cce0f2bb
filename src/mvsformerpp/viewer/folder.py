"""Read a ``reconstruct`` output folder for presentation: run facts, per-view maps, SfM outcome.

Everything here only reads; a folder written by an older version or an interrupted run gives what
it has (missing parts are ``None``), so the report and the viewer can show partial results.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mvsformerpp.errors import InputError
from mvsformerpp.io.images import find_image, read_image
from mvsformerpp.io.mvsnet import cam_files, read_cam
from mvsformerpp.io.pfm import read_pfm


@dataclass
class ViewFiles:
    """One view of an output folder: its files and camera (paths are None when absent)."""

    stem: str
    name: str
    image: Path | None
    depth: Path | None
    confidence: Path | None
    cam: Path | None

    def read_depth(self) -> np.ndarray | None:
        return None if self.depth is None else read_pfm(self.depth)

    def read_confidence(self) -> np.ndarray | None:
        return None if self.confidence is None else read_pfm(self.confidence)

    def read_image(self) -> np.ndarray | None:
        return None if self.image is None else read_image(self.image)


@dataclass
class RunFolder:
    """The parts of an output folder that the report and the viewer show."""

    root: Path
    config: dict[str, Any] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)
    views: list[ViewFiles] = field(default_factory=list)
    sfm: dict[str, Any] | None = None

    @property
    def cloud(self) -> Path | None:
        """``fused.ply`` of the folder, if there is one."""
        ply = self.root / "fused.ply"
        return ply if ply.is_file() else None


def _json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read {path.name} ({e})", path) from e


def open_run(root: str | Path) -> RunFolder:
    """Read an output folder; :class:`InputError` when it holds no reconstruction at all."""
    root = Path(root)
    if not root.is_dir():
        raise InputError("no such output folder (make one with `mvsformerpp reconstruct INPUT -o OUT`)", root)
    cams = cam_files(root / "cams") if (root / "cams").is_dir() else {}
    if not cams:
        raise InputError("not a reconstruct output folder (no cams/ inside); make one with "
                         "`mvsformerpp reconstruct INPUT -o OUT`", root)
    names = _json(root / "views.json")
    views = []
    for i in sorted(cams):
        stem = f"{i:08d}"
        depth, conf = root / "depth_est" / f"{stem}.pfm", root / "confidence" / f"{stem}.pfm"
        views.append(ViewFiles(stem=stem, name=names.get(stem, stem), image=find_image(root / "images", stem),
                               depth=depth if depth.is_file() else None,
                               confidence=conf if conf.is_file() else None, cam=cams[i]))
    return RunFolder(root=root, config=_json(root / "config.json"), summary=_json(root / "summary.json"),
                     views=views, sfm=sfm_outcome(root / "sfm"))


def sfm_outcome(sfm_dir: Path) -> dict[str, Any] | None:
    """``sfm/report.json`` when structure-from-motion ran, else statistics of ``sfm/model``, else None."""
    report = sfm_dir / "report.json"
    if report.is_file():
        return _json(report)
    if not (sfm_dir / "model").is_dir():
        return None
    from mvsformerpp.io.colmap_model import read_model
    from mvsformerpp.io.colmap_stats import model_statistics

    return model_statistics(read_model(sfm_dir / "model"))


def depth_range_of(view: ViewFiles) -> tuple[float, float] | None:
    """The depth range of a view's camera file (the range the network searched)."""
    if view.cam is None:
        return None
    cam = read_cam(view.cam)
    if cam.depth_min is None or cam.depth_max is None:
        return None
    return float(cam.depth_min), float(cam.depth_max)
