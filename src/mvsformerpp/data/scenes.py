"""Training samples from calibrated scenes on disk (DTU, BlendedMVS, any :class:`~mvsformerpp.io.scene.Scene`
whose views carry ground-truth depth), and the balanced mix of several datasets.

A :class:`SceneDataset` is a thin layer over :class:`~mvsformerpp.data.base.MVSDataset`: a sample is
(scene, reference view, image variant), where a variant renames the photo (DTU's seven lightings are
the same cameras with other photos). Source views: ``num_views - 1`` drawn at random from the
reference's first ``num_candidates`` pair.txt neighbours (padded by repetition when there are fewer),
as the reference's training loaders do. Mask: the scene's mask image ``> 10`` where it has one
(DTU ``depth_visual``), and depth ``> 0``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvsformerpp.data.base import MVSDataset, SampleKey, ViewData, ViewSet
from mvsformerpp.errors import InputError
from mvsformerpp.io.images import read_image
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.scene import Scene


@dataclass
class SceneEntry:
    """One scene with one photo variant."""

    name: str
    scene: Scene
    image_path: Callable[[int], Path] | None = None
    """Photo of view i (None: the scene's own ``image_path``)."""


def draw_sources(scene: Scene, ref: int, num_views: int, num_candidates: int, rng: np.random.Generator) -> list[int]:
    """``num_views - 1`` source views drawn at random from the reference's first ``num_candidates`` neighbours
    (repeated when there are fewer), as the reference's training loaders draw them."""
    cands = [j for j in scene.views[ref].neighbors if j != ref][:num_candidates]
    picked = [cands[k] for k in rng.permutation(len(cands))[: num_views - 1]]
    return picked + [picked[0]] * (num_views - 1 - len(picked))


def read_mask(path: Path) -> np.ndarray:
    """A mask image as bool [H, W]: value > 10 (the reference's DTU ``depth_visual`` rule)."""
    from PIL import Image

    with Image.open(path) as im:
        a = np.asarray(im.convert("L"), dtype=np.uint8)
    return a > 10


class SceneDataset(MVSDataset):
    """Samples = every view with ground-truth depth and at least one neighbour, of every entry."""

    def __init__(self, entries: Sequence[SceneEntry], num_views: int = 5, num_candidates: int = 10, **kwargs):
        super().__init__(**kwargs)
        self.entries = list(entries)
        self.num_views, self.num_candidates = int(num_views), int(num_candidates)
        self.samples: list[tuple[int, int]] = []
        for e, entry in enumerate(self.entries):
            for i, v in enumerate(entry.scene.views):
                if v.depth_gt_path is not None and v.neighbors and v.depth_min is not None:
                    self.samples.append((e, i))
        if not self.samples:
            raise InputError("no view with ground-truth depth, neighbours and a depth range in "
                             + ", ".join(e.name for e in self.entries[:5]))

    def __len__(self) -> int:
        return len(self.samples)

    def describe(self, index: int) -> str:
        e, i = self.samples[index]
        return f"{self.entries[e].name} view {self.entries[e].scene.views[i].name}"

    def _photo(self, entry: SceneEntry, i: int) -> np.ndarray:
        path = entry.image_path(i) if entry.image_path else entry.scene.views[i].image_path
        if not path.is_file():
            raise InputError("photo missing (expected by the data set layout)", path)
        return read_image(path)

    def load_views(self, index: int, rng: np.random.Generator, height: int, width: int) -> ViewSet:
        e, ref = self.samples[index]
        entry = self.entries[e]
        scene = entry.scene
        picked = draw_sources(scene, ref, self.num_views, self.num_candidates, rng)
        views = []
        for k, i in enumerate([ref] + picked):
            v = scene.views[i]
            image = self._photo(entry, i)
            K = np.array(v.K, dtype=np.float64)
            if image.shape[:2] != (v.height, v.width):  # K belongs to the size the scene reader saw
                K[0] *= image.shape[1] / v.width
                K[1] *= image.shape[0] / v.height
            depth = mask = None
            if k == 0:
                depth = read_pfm(v.depth_gt_path).astype(np.float32)
                if depth.ndim == 3:
                    depth = depth[..., 0]
                mask = read_mask(v.mask_path) if v.mask_path is not None else np.ones(depth.shape, bool)
                if mask.shape != depth.shape:
                    raise InputError(f"mask is {mask.shape[1]}x{mask.shape[0]}, depth {depth.shape[1]}x"
                                     f"{depth.shape[0]}", v.mask_path)
                mask &= depth > 0
                if depth.shape != image.shape[:2]:
                    raise InputError(f"depth map is {depth.shape[1]}x{depth.shape[0]} but the photo is "
                                     f"{image.shape[1]}x{image.shape[0]}", v.depth_gt_path)
            views.append(ViewData(image, K, v.extrinsic, depth, mask))
        r = scene.views[ref]
        return ViewSet(views, float(r.depth_min), float(r.depth_max))


class BalancedMix(MVSDataset):
    """Several datasets with the same number of samples each (the largest one's length): sample ``i``
    is item ``(i // k) mod len_d`` of dataset ``d = i mod k``, so every batch mixes them evenly."""

    def __init__(self, datasets: Sequence[MVSDataset]):
        super().__init__()
        self.datasets = list(datasets)
        self.per = max(len(d) for d in self.datasets)

    def __len__(self) -> int:
        return self.per * len(self.datasets)

    def describe(self, index: int) -> str:
        d, j = self._locate(index)
        return self.datasets[d].describe(j)

    def _locate(self, index: int) -> tuple[int, int]:
        k = len(self.datasets)
        d = index % k
        return d, (index // k) % len(self.datasets[d])

    def __getitem__(self, key: SampleKey) -> dict:
        d, j = self._locate(key.index)
        return self.datasets[d][SampleKey(j, key.height, key.width, key.epoch)]
