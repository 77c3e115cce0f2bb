"""The reconstruction output folder: per-view outputs, resumable progress, scene identity.

Layout (binding for fusion, which reads it with the MVSNet reader):
``images/NNNNNNNN.<ext>``, ``cams/NNNNNNNN_cam.txt``, ``pair.txt``, ``depth_est/NNNNNNNN.pfm``,
``confidence/NNNNNNNN.pfm``, ``depth_vis/NNNNNNNN.png``, ``confidence_vis/NNNNNNNN.png``, ``fused.ply``,
``config.json``, ``summary.json``, ``views.json``; plus ``progress.json`` (which views are done and with
which settings, and the depth range stage 1 searched where ``--min-parallax`` widened the camera's) and
``sfm/`` when structure-from-motion ran.

Everything that knows this layout is here: :class:`OutputFolder` writes it (``reconstruct``), the
readers below (:func:`open_run`, :func:`read_run_record`, :func:`require_depth_maps`) serve ``fuse``,
``mesh``, ``export``, ``report`` and ``view``.

Every file is written to a temporary name and renamed (:mod:`mvsformerpp.utils.atomic`); a view counts
as done only once all four of its files exist and ``progress.json`` records it with the current
settings hash, so an interrupted run never leaves a view that looks done but is not.
"""

from __future__ import annotations

import errno
import filecmp
import hashlib
import json
import os
import shutil
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from mvsformerpp.errors import InputError, MVSFormerError
from mvsformerpp.io.colmap_model import read_model
from mvsformerpp.io.colmap_stats import model_statistics
from mvsformerpp.io.images import find_image, image_size, read_image
from mvsformerpp.io.mvsnet import cam_files, read_cam
from mvsformerpp.io.pfm import read_pfm, write_pfm
from mvsformerpp.io.scene import Scene
from mvsformerpp.utils.atomic import atomic_open, atomic_write_text
from mvsformerpp.utils.colormap import confidence_to_png, depth_to_png
from mvsformerpp.utils.file_kinds import HTML_REPORT, POINT_CLOUD

CAMS, IMAGES, DEPTH, CONFIDENCE = "cams", "images", "depth_est", "confidence"
DEPTH_VIS, CONFIDENCE_VIS = "depth_vis", "confidence_vis"
CONFIG, SUMMARY, VIEWS, PROGRESS = "config.json", "summary.json", "views.json", "progress.json"
CLOUD, REPORT = POINT_CLOUD.run_name, HTML_REPORT.run_name  # fused.ply, report.html: no other kind takes these


def require_depth_maps(root: str | Path) -> Path:
    """``root`` as a folder that holds cameras and depth maps; else an :class:`InputError` saying how to make one."""
    root = Path(root)
    if not root.is_dir():
        raise InputError("no such output folder (make one with `mvsformerpp reconstruct INPUT -o OUT`)", root)
    if not (root / CAMS).is_dir() or not (root / DEPTH).is_dir():
        raise InputError(f"no depth maps here ({CAMS}/ and {DEPTH}/); make them with "
                         "`mvsformerpp reconstruct INPUT -o OUT`", root)
    return root


def require_cloud(root: str | Path) -> Path:
    """The fused cloud of ``root``; else an :class:`InputError` saying how to make it."""
    ply = Path(root) / CLOUD
    if not ply.is_file():
        raise InputError(f"no fused cloud ({CLOUD}); make it with `mvsformerpp fuse OUT` "
                         "(or `mvsformerpp reconstruct INPUT -o OUT` with fusion on)", root)
    return ply


class DiskFullError(MVSFormerError):
    """The disk filled up while writing an output."""


@contextmanager
def disk_full_guard(what: Path):
    """Turn ENOSPC/EDQUOT while writing ``what`` into a clear :class:`DiskFullError`."""
    try:
        yield
    except OSError as e:
        if e.errno in (errno.ENOSPC, errno.EDQUOT):
            raise DiskFullError(
                f"{what}: the disk is full (no space left while writing). Free some space and run the same "
                "command again: finished views are kept and the run continues where it stopped"
            ) from e
        raise


def read_run_record(root: str | Path) -> dict | None:
    """``config.json`` of a ``reconstruct`` output folder (its settings, resolved values, scene identity), or
    None when ``root`` holds no readable one (another tool's depth maps)."""
    try:
        record = json.loads((Path(root) / CONFIG).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("config"), dict) else None


def recorded_fusion_size(root: str | Path) -> int | None:
    """The working resolution (longer side) the run of ``root`` computed its depth maps at, when it asks
    fusion to read them at it (``fusion_resolution`` working, the default), else None."""
    record = read_run_record(root)
    try:
        size = record["resolved"]["long_side"]
        wanted = record["config"].get("fusion_resolution", "original")
    except (TypeError, KeyError, AttributeError):
        return None
    return int(size) if wanted == "working" and isinstance(size, int) else None


def view_stem(i: int) -> str:
    return f"{i:08d}"


def scene_fingerprint(scene: Scene) -> str:
    """A hash of what identifies a scene: view names, image sizes and camera poses/intrinsics."""
    h = hashlib.sha256()
    for v in scene.views:
        h.update(v.name.encode())
        h.update(f"{v.width}x{v.height}".encode())
        for a in (v.K, v.R, v.t):
            h.update(np.round(np.asarray(a, dtype=np.float64), 6).tobytes())
    return h.hexdigest()[:16]


def settings_hash(settings: dict) -> str:
    return hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]


class OutputFolder:
    """Reads and writes one reconstruction output folder.

    Several processes may write views into one folder (ranks of a torchrun run, :mod:`.ranks`): rank 0
    owns ``progress.json``; rank r > 0 records the views it writes in ``progress.rank<r>.json``, which
    rank 0 folds into ``progress.json`` (:meth:`fold_rank_progress`) when the ranks are done, and at
    its next start if a run stopped before that (a rank file is newer than ``progress.json`` for the
    views it lists: a view is written by one rank per run, and every run starts by folding).
    """

    def __init__(self, root: str | Path, rank: int = 0):
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise InputError("the output path exists and is not a folder; choose another -o", self.root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.rank = int(rank)
        main = self.root / PROGRESS
        self.progress_path = main if self.rank == 0 else self.root / f"progress.rank{self.rank}.json"
        self.progress = self._read_json(main) or {"views": {}, "fusion": None}
        if self.rank == 0:
            self.fold_rank_progress()
        else:  # this rank's own record: only the views it writes
            self.progress = {"views": {}, "fusion": None}

    @property
    def cloud(self) -> Path:
        return self.root / CLOUD

    @property
    def report(self) -> Path:
        return self.root / REPORT

    def fold_rank_progress(self) -> None:
        """Rank 0: merge the other ranks' progress files into ``progress.json`` and remove them."""
        files = sorted(self.root.glob("progress.rank*.json"))
        if not files:
            return
        for f in files:
            record = self._read_json(f) or {}
            self.progress["views"].update(record.get("views", {}))
            ranges = self.progress.setdefault("searched", {})
            for k, searched in record.get("searched", {}).items():
                if searched is None:
                    ranges.pop(k, None)
                else:
                    ranges[k] = searched
        self.save_progress()
        for f in files:
            f.unlink(missing_ok=True)

    def _read_json(self, path: Path) -> dict | None:
        if not path.is_file():
            return None
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read {path.name} ({e}); delete it or choose another -o", path) from e

    def paths(self, i: int) -> dict[str, Path]:
        s = view_stem(i)
        return {
            "depth": self.root / DEPTH / f"{s}.pfm",
            "confidence": self.root / CONFIDENCE / f"{s}.pfm",
            "depth_vis": self.root / DEPTH_VIS / f"{s}.png",
            "confidence_vis": self.root / CONFIDENCE_VIS / f"{s}.png",
        }

    def check_scene(self, fingerprint: str) -> None:
        """Refuse a folder that holds the outputs of a different scene."""
        stored = self._read_json(self.root / CONFIG)
        if stored is not None and stored.get("scene_fingerprint") not in (None, fingerprint):
            raise InputError(
                "this output folder holds the reconstruction of a different scene (its config.json has another "
                "scene fingerprint). Choose a new -o folder, or delete this one to start over",
                self.root,
            )

    def view_done(self, i: int, state: str) -> bool:
        return self.progress["views"].get(str(i)) == state and all(p.is_file() for p in self.paths(i).values())

    def write_view(self, i: int, depth: np.ndarray, confidence: np.ndarray, state: str,
                   preview_conf: float | None = None, searched: tuple[float, float, float] | None = None) -> None:
        """Write the four files of view ``i``, then record it as done. The depth preview greys the pixels
        whose confidence is at most ``preview_conf`` (those fusion drops; None: none greyed). ``searched``:
        ``(depth_min, depth_max, factor)`` of a stage-1 range wider than the camera's (None: the camera's)."""
        p = self.paths(i)
        with disk_full_guard(p["depth"]):
            write_pfm(p["depth"], depth)
            write_pfm(p["confidence"], confidence)
            depth_to_png(p["depth_vis"], depth, confidence, preview_conf)
            confidence_to_png(p["confidence_vis"], confidence)
            self.progress["views"][str(i)] = state
            ranges = self.progress.setdefault("searched", {})
            if searched is not None or self.rank > 0:  # (None tells rank 0's fold to forget an older range)
                ranges[str(i)] = None if searched is None else [float(x) for x in searched]
            else:
                ranges.pop(str(i), None)
            self.save_progress()

    def redraw_previews(self, views: list[int], preview_conf: float | None) -> None:
        """Main process, before new views are written: make the depth previews of the finished ``views``
        follow ``preview_conf`` when they were drawn for another threshold (a run again with ``--conf``)."""
        if self.progress.get("preview_conf", "unset") == preview_conf:
            return
        for i in views:
            p = self.paths(i)
            if p["depth"].is_file() and p["confidence"].is_file():
                with disk_full_guard(p["depth_vis"]):
                    depth_to_png(p["depth_vis"], read_pfm(p["depth"]), read_pfm(p["confidence"]), preview_conf)
        self.progress["preview_conf"] = preview_conf
        self.save_progress()

    def fusion_done(self, state: str) -> bool:
        return self.progress.get("fusion") == state and self.cloud.is_file()

    def mark_fusion(self, state: str) -> None:
        self.progress["fusion"] = state
        self.save_progress()

    def save_progress(self) -> None:
        with disk_full_guard(self.progress_path):
            atomic_write_text(self.progress_path, json.dumps(self.progress, indent=1, sort_keys=True))

    def write_json(self, name: str, data: dict) -> Path:
        path = self.root / name
        with disk_full_guard(path):
            atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True, default=str) + "\n")
        return path

    def write_working_image(self, i: int, src: Path, plan) -> Path:
        """``images/NNNNNNNN<ext>``: the photo at the working resolution of ``plan`` (a
        :class:`~mvsformerpp.inference.resolution.ViewResize`), the pixels the network sees; kept
        when one of that size is already there."""

        dst = self.root / IMAGES / f"{view_stem(i)}{src.suffix.lower()}"
        if dst.is_file() and not dst.is_symlink() and dst.stat().st_nlink == 1 and \
                image_size(dst) == (plan.resized_width, plan.resized_height):
            return dst
        fmt = Image.registered_extensions().get(dst.suffix, "PNG")
        with disk_full_guard(dst), atomic_open(dst, "wb") as f:
            Image.fromarray(plan.working_image(read_image(src))).save(f, format=fmt,
                                                                      **({"quality": 95} if fmt == "JPEG" else {}))
        return dst

    def link_image(self, i: int, src: Path) -> Path:
        """``images/NNNNNNNN<ext>``: a hard link to the input photo, or a copy across file systems."""
        dst = self.root / IMAGES / f"{view_stem(i)}{src.suffix.lower()}"
        if dst.is_file() and (os.path.samefile(src, dst) or filecmp.cmp(src, dst, shallow=False)):
            return dst
        dst.parent.mkdir(parents=True, exist_ok=True)
        with disk_full_guard(dst):
            tmp = dst.with_name(f".{dst.name}.link")
            try:
                if tmp.exists():
                    tmp.unlink()
                os.link(src, tmp)
                os.replace(tmp, dst)
            except OSError as e:
                if e.errno in (errno.ENOSPC, errno.EDQUOT):
                    raise
                with atomic_open(dst, "wb") as f, open(src, "rb") as fin:
                    shutil.copyfileobj(fin, f)
        return dst


# ------------------------------------------------------------------------------- reading, for presentation


@dataclass
class ViewFiles:
    """One view of an output folder: its files and camera (paths are None when absent)."""

    stem: str
    name: str
    image: Path | None
    depth: Path | None
    confidence: Path | None
    cam: Path | None
    searched: tuple[float, float, float] | None = None
    """``(depth_min, depth_max, factor)`` when stage 1 searched a range wider than the camera's."""

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
        ply = self.root / CLOUD
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
    cams = cam_files(root / CAMS) if (root / CAMS).is_dir() else {}
    if not cams:
        raise InputError("not a reconstruct output folder (no cams/ inside); make one with "
                         "`mvsformerpp reconstruct INPUT -o OUT`", root)
    names = _json(root / VIEWS)
    searched = _json(root / PROGRESS).get("searched") or {}
    views = []
    for i in sorted(cams):
        stem = f"{i:08d}"
        depth, conf = root / DEPTH / f"{stem}.pfm", root / CONFIDENCE / f"{stem}.pfm"
        views.append(ViewFiles(stem=stem, name=names.get(stem, stem), image=find_image(root / IMAGES, stem),
                               depth=depth if depth.is_file() else None,
                               confidence=conf if conf.is_file() else None, cam=cams[i],
                               searched=tuple(searched[str(i)]) if searched.get(str(i)) else None))
    return RunFolder(root=root, config=_json(root / CONFIG), summary=_json(root / SUMMARY),
                     views=views, sfm=sfm_outcome(root / "sfm"))


def sfm_outcome(sfm_dir: Path) -> dict[str, Any] | None:
    """``sfm/report.json`` when structure-from-motion ran, else statistics of ``sfm/model``, else None."""
    report = sfm_dir / "report.json"
    if report.is_file():
        return _json(report)
    if not (sfm_dir / "model").is_dir():
        return None

    return model_statistics(read_model(sfm_dir / "model"))


def depth_range_of(view: ViewFiles) -> tuple[float, float] | None:
    """The depth range of a view's camera file (what the network searched unless ``view.searched`` says)."""
    if view.cam is None:
        return None
    cam = read_cam(view.cam)
    if cam.depth_min is None or cam.depth_max is None:
        return None
    return float(cam.depth_min), float(cam.depth_max)
