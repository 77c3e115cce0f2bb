"""Real calibrated photos for training without ground-truth depth: self-supervision and teacher labels.

A :class:`RealSceneDataset` reads scenes in any layout :func:`~mvsformerpp.io.detect.load_scene` knows
(LLFF, IDR, COLMAP, MVSNet, ...). Its samples come in pairs: sample ``2m`` has a view ``i`` of a scene as
its reference and sample ``2m + 1`` the best neighbour of ``i`` (both with ``pair_id`` ``m``), so a batch that
keeps the pair together can ask their depths to agree
(:func:`~mvsformerpp.training.self_supervision.cross_view_error`). Source views are drawn from the
reference's neighbours (:func:`~mvsformerpp.data.scenes.draw_sources`); the depth range is the
scene's own (LLFF bounds, IDR sphere, sparse points).

``labels``: a folder of teacher depth maps, ``LABELS/<scene>/<view>.pfm`` (0 = no label; written by
``tools/teacher_labels.py``): where one exists the reference's depth is that map, and the cross-entropy
trains on it (distillation); ``self_supervised``: the samples are also scored by photometric consistency.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mvsformerpp.data.base import MVSDataset, ViewData, ViewSet
from mvsformerpp.data.scenes import draw_sources
from mvsformerpp.errors import InputError
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.images import read_image
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.scene import Scene


def scene_name(path: str | Path) -> str:
    """The name a scene's labels are filed under: its folder's name (a camera file: the folder holding it)."""
    p = Path(path)
    return p.parent.name if p.is_file() else p.name


def load_real_scenes(paths: Sequence[str | Path]) -> list[tuple[str, Scene]]:
    """(name, scene) of every path, each checked: cameras that fit their photos, a depth range, neighbours."""
    out = []
    for path in paths:
        scene = load_scene(path)
        missing = [v.name for v in scene.views if v.depth_min is None]
        if missing:
            raise InputError(f"{len(missing)} views have no depth range (e.g. {missing[0]}): a training scene needs "
                             "each view's range (cam files' depth lines, LLFF bounds, an IDR sphere or sparse points)",
                             path)
        if not any(v.neighbors for v in scene.views):
            raise InputError("no view has a neighbour: the photos of a training scene must overlap", path)
        out.append((scene_name(path), scene))
    names = [n for n, _ in out]
    if len(set(names)) != len(names):
        raise InputError(f"two real scenes share a folder name ({names}): their labels would mix; rename one")
    return out


class RealSceneDataset(MVSDataset):
    """Pairs of references from real scenes (module docstring)."""

    def __init__(self, scenes: Sequence[tuple[str, Scene]], num_views: int = 5, num_candidates: int = 10,
                 labels: str | Path | None = None, self_supervised: bool = True, **kwargs):
        super().__init__(**kwargs)
        self.scenes = list(scenes)
        self.num_views, self.num_candidates = int(num_views), int(num_candidates)
        self.labels = Path(labels) if labels is not None else None
        self.self_supervised = bool(self_supervised)
        self.samples: list[tuple[int, int]] = []
        for s, (_, scene) in enumerate(self.scenes):
            for i, v in enumerate(scene.views):
                if v.neighbors:
                    self.samples += [(s, i), (s, v.neighbors[0])]
        if not self.samples:
            raise InputError("the real scenes have no view with a neighbour")

    def __len__(self) -> int:
        return len(self.samples)

    def describe(self, index: int) -> str:
        s, i = self.samples[index]
        return f"real scene {self.scenes[s][0]} view {self.scenes[s][1].views[i].name}"

    def label(self, s: int, i: int) -> np.ndarray | None:
        """The teacher's depth of view ``i`` of scene ``s`` (None: no labels, or none for this view)."""
        if self.labels is None:
            return None
        path = self.labels / self.scenes[s][0] / f"{self.scenes[s][1].views[i].name}.pfm"
        if not path.is_file():
            return None
        depth = read_pfm(path).astype(np.float32)
        return depth[..., 0] if depth.ndim == 3 else depth

    def load_views(self, index: int, rng: np.random.Generator, height: int, width: int) -> ViewSet:
        s, ref = self.samples[index]
        scene = self.scenes[s][1]
        picked = draw_sources(scene, ref, self.num_views, self.num_candidates, rng)
        views = []
        for k, i in enumerate([ref] + picked):
            v = scene.views[i]
            image = read_image(v.image_path)
            if image.shape[:2] != (v.height, v.width):
                raise InputError(f"photo is {image.shape[1]}x{image.shape[0]}, its camera {v.width}x{v.height}",
                                 v.image_path)
            depth = self.label(s, i) if k == 0 else None
            if depth is not None and depth.shape != image.shape[:2]:
                raise InputError(f"label is {depth.shape[1]}x{depth.shape[0]}, the photo {v.width}x{v.height}; make "
                                 "the labels again for these photos", self.labels)
            views.append(ViewData(image, v.K.copy(), v.extrinsic, depth, None if depth is None else depth > 0))
        r = scene.views[ref]
        return ViewSet(views, float(r.depth_min), float(r.depth_max), self_supervised=self.self_supervised,
                       pair_id=index // 2)
