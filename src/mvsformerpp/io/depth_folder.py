"""Reading a folder of depth maps: ``reconstruct``'s output layout, which MVSNet-family test scripts share.

``images/``, ``cams/NNNNNNNN_cam.txt``, ``pair.txt``, ``depth_est/NNNNNNNN.pfm`` and
``confidence/NNNNNNNN.pfm`` (or ``.png`` holding confidence x 255) (:mod:`.output_folder` writes them).
Depth maps may be smaller than the images (the cameras are then scaled to them). :class:`DepthFolder` checks
a folder up front and reads one view at a time (fusion streams through it, the quality checks and
the empty-cloud advice read it); :func:`load_depth_folder` reads all of it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.geometry.resize import fit_long_side
from mvsformerpp.io.images import read_image
from mvsformerpp.io.masks import check_mask_size, fit_mask, mask_paths, read_mask
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.output_folder import CONFIDENCE, DEPTH, VIEWS
from mvsformerpp.io.pfm import pfm_shape, read_pfm
from mvsformerpp.io.scene import Scene


def _confidence_path(folder: Path, stem: str) -> Path | None:
    for ext in (".pfm", ".png"):
        path = folder / CONFIDENCE / f"{stem}{ext}"
        if path.is_file():
            return path
    return None


def _read_confidence(path: Path, shape) -> np.ndarray:
    conf = read_pfm(path) if path.suffix == ".pfm" else read_image(path)[..., 0].astype(np.float32) / 255.0
    if conf.shape != shape:
        raise FormatError(f"confidence map is {conf.shape[1]}x{conf.shape[0]}, its depth map {shape[1]}x{shape[0]}",
                          path)
    return conf


MIN_READ_SIZE = 16
"""Smallest longer side, in pixels, that fusion reads depth maps at."""


def fusion_read_size(max_size: int | None) -> int | None:
    """The longer side fusion reads depth maps at, at most (``fuse --max-size``): None or 0 is the size they
    are stored at; else it must be at least :data:`MIN_READ_SIZE`."""
    if not max_size:
        return None
    if max_size < MIN_READ_SIZE:
        raise InputError(f"--max-size must be at least {MIN_READ_SIZE} pixels (or 0: the stored size), got {max_size}")
    return max_size


class DepthFolder:
    """The depth maps of a scene folder, checked up front and read one view at a time.

    With ``mask_dir`` (:mod:`mvsformerpp.io.masks`), depths outside each view's object mask read as 0.
    With ``max_size``, maps whose longer side exceeds it read at that size (:meth:`_resample`): depth maps
    upsampled to large photos fuse at the resolution they were computed at.
    """

    def __init__(self, folder: str | Path, mask_dir: str | Path | None = None, max_size: int | None = None):
        self.root = Path(folder)
        self.max_size = fusion_read_size(max_size)
        self.scene: Scene = load_mvsnet_scene(self.root)
        missing = [p.name for p in map(self.depth_path, range(len(self.scene))) if not p.is_file()]
        if missing:
            raise InputError(
                f"{len(missing)} of {len(self.scene)} views have no depth map in {DEPTH}/ (e.g. {missing[0]}); "
                "run reconstruct first or remove those views' cams", self.root)
        self.confidence_paths = [_confidence_path(self.root, v.name) for v in self.scene.views]
        has_conf = [p is not None for p in self.confidence_paths]
        if any(has_conf) and not all(has_conf):
            raise InputError("some views have a confidence map and others not (confidence/)", self.root)
        self.has_confidence = all(has_conf)
        self.mask_paths = None
        if mask_dir is not None:
            names_file = self.root / VIEWS  # the photos' original names, as reconstruct records them
            original = json.loads(names_file.read_text()) if names_file.is_file() else {}
            names = [original.get(v.name, v.image_path.name) for v in self.scene.views]
            self.mask_paths = mask_paths(mask_dir, names)
            for i, p in enumerate(self.mask_paths):
                check_mask_size(p, *self.depth_shape(i))

    def depth_path(self, i: int) -> Path:
        return self.root / DEPTH / f"{self.scene.views[i].name}.pfm"

    def stored_shape(self, i: int) -> tuple[int, int]:
        """(height, width) of view i's depth map file."""
        shape = pfm_shape(self.depth_path(i))
        if len(shape) != 2:
            raise FormatError("depth map must have one channel (Pf)", self.depth_path(i))
        (h, w), view = shape, self.scene.views[i]
        if abs(w * view.height - h * view.width) > max(w, h, view.width, view.height):  # > 1 px off the aspect
            raise FormatError(f"depth map is {w}x{h}, which is not the shape of its {view.width}x{view.height} photo "
                              "(depth maps may be smaller than the photos, with the same aspect ratio)",
                              self.depth_path(i))
        return h, w

    def depth_shape(self, i: int) -> tuple[int, int]:
        """(height, width) view i's maps are read at (the stored size, or less under ``max_size``)."""
        h, w = self.stored_shape(i)
        if self.max_size is None:
            return h, w
        w, h = fit_long_side(w, h, self.max_size)
        return h, w

    def _resample(self, i: int, depth: np.ndarray, conf: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Depth (and confidence) at the centres of the smaller grid: interpolated between the four nearest
        pixels where they lie on one smooth surface (all with depth, within 1 % of each other), else the
        nearest pixel's (no depth is made up across an edge)."""
        h, w = self.depth_shape(i)
        H, W = depth.shape
        if (h, w) == (H, W):
            return depth, conf
        y = np.clip((np.arange(h) + 0.5) * H / h - 0.5, 0, H - 1)
        x = np.clip((np.arange(w) + 0.5) * W / w - 0.5, 0, W - 1)
        y0, x0 = np.minimum(y.astype(np.int64), H - 2), np.minimum(x.astype(np.int64), W - 2)
        fy, fx = (y - y0)[:, None], (x - x0)[None, :]

        def corners(a):
            return a[y0][:, x0], a[y0][:, x0 + 1], a[y0 + 1][:, x0], a[y0 + 1][:, x0 + 1]

        def blend(c):
            return (c[0] * (1 - fx) + c[1] * fx) * (1 - fy) + (c[2] * (1 - fx) + c[3] * fx) * fy

        def nearest(a):
            return a[np.round(y).astype(np.int64)][:, np.round(x).astype(np.int64)]

        d = corners(depth.astype(np.float64))
        lo, hi = np.minimum.reduce(d), np.maximum.reduce(d)
        smooth = (lo > 0) & (hi - lo <= 0.01 * lo)
        out = np.where(smooth, blend(d), nearest(depth)).astype(depth.dtype)
        if conf is not None:
            conf = np.where(smooth, blend(corners(conf.astype(np.float64))), nearest(conf)).astype(conf.dtype)
        return np.ascontiguousarray(out), conf

    def read(self, i: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """View i's (depth, confidence or None, image)."""
        path = self.depth_path(i)
        depth = read_pfm(path)
        if depth.ndim != 2:
            raise FormatError("depth map must have one channel (Pf)", path)
        conf = _read_confidence(self.confidence_paths[i], depth.shape) if self.has_confidence else None
        depth, conf = self._resample(i, depth, conf)
        if self.mask_paths is not None:
            mask = fit_mask(read_mask(self.mask_paths[i]), *depth.shape, self.mask_paths[i])
            depth = np.where(mask, depth, 0).astype(depth.dtype)
        return depth, conf, read_image(self.scene.views[i].image_path)


def load_depth_folder(folder: str | Path):
    """(scene, depths, confidences or None, images) of a scene folder with ``depth_est/``, all in memory."""
    f = DepthFolder(folder)
    maps = [f.read(i) for i in range(len(f.scene))]
    return f.scene, [m[0] for m in maps], ([m[1] for m in maps] if f.has_confidence else None), [m[2] for m in maps]
