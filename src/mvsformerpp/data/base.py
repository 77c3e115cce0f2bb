"""The one dataset base for training and validation: view sets in, the network's tensors out.

A subclass says what a sample is (``__len__``) and how to read its views (:meth:`load_views`): the
reference view first, then the source views, each an uint8 photo with its intrinsics, world-to-camera
matrix and (for the reference) ground-truth depth and mask. The base does everything else the same
way for every data source: the multi-scale resize and crop to the batch's resolution with intrinsics
adjusted (:mod:`.transforms`), the photometric augmentation shared by a sample's views, ImageNet
normalisation, the per-stage projection matrices and the per-stage ground truth (nearest
downsampling, as the reference's ``cv2.INTER_NEAREST``).

Items are addressed by a :class:`SampleKey` (index, resolution, epoch) that the batch sampler
(:mod:`.samplers`) produces, so one dataset serves every resolution of a multi-scale run. All
randomness of an item comes from a generator seeded by (dataset seed, epoch, index): a run is
reproducible and resumable regardless of worker processes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from mvsformerpp.data.transforms import PhotometricAugment, ResizeCrop
from mvsformerpp.models.inputs import STAGE_SCALES, normalize, stage_projections


@dataclass
class ViewData:
    """One view of a sample at its source resolution."""

    image: np.ndarray
    """uint8 [H, W, 3] RGB."""
    K: np.ndarray
    """3x3 intrinsics for this image's pixel grid."""
    E: np.ndarray
    """4x4 world-to-camera."""
    depth: np.ndarray | None = None
    """float32 [H, W] ground-truth z-depth (reference view; 0 = unknown)."""
    mask: np.ndarray | None = None
    """bool [H, W] pixels to supervise (reference view)."""


@dataclass
class ViewSet:
    """The views of one sample (reference first) and the depth range of the reference."""

    views: list[ViewData]
    depth_min: float
    depth_max: float
    self_supervised: bool = False
    """The sample is scored by photometric consistency (:mod:`mvsformerpp.training.self_supervision`), not (only)
    by its depth."""
    pair_id: int = -1
    """Samples with the same id >= 0 are references of one scene whose depths should agree (-1: none)."""


@dataclass(frozen=True)
class SampleKey:
    """What the batch sampler asks for: sample ``index`` at ``height`` x ``width`` in ``epoch``."""

    index: int
    height: int
    width: int
    epoch: int = 0


class MVSDataset(Dataset):
    """Base of every training/validation set (see the module docstring).

    Args:
        seed: seeds every item's generator together with the epoch and the index.
        num_depth: length of the ``depth_values`` vector (only its first and last entries matter).
        resize_crop: the multi-scale resize and crop (None: views must already have the size asked).
        photometric: colour jitter and gamma, shared by a sample's views (None: no augmentation).
    """

    def __init__(self, seed: int = 0, num_depth: int = 192, resize_crop: ResizeCrop | None = None,
                 photometric: PhotometricAugment | None = None):
        self.seed = int(seed)
        self.num_depth = int(num_depth)
        self.resize_crop = resize_crop
        self.photometric = photometric

    def __len__(self) -> int:
        raise NotImplementedError

    def load_views(self, index: int, rng: np.random.Generator, height: int, width: int) -> ViewSet:
        """The views of sample ``index``; ``height`` x ``width`` is the size the batch will have
        (a generator may render at it; a file reader ignores it)."""
        raise NotImplementedError

    def describe(self, index: int) -> str:
        """A short name of sample ``index`` for error messages."""
        return f"sample {index}"

    def rng(self, key: SampleKey) -> np.random.Generator:
        return np.random.default_rng([self.seed, key.epoch, key.index])

    def views(self, key: SampleKey, rng: np.random.Generator | None = None) -> ViewSet:
        """The views of an item after the resize and crop: what the network is fed, as photos and cameras."""
        rng = self.rng(key) if rng is None else rng
        vs = self.load_views(key.index, rng, key.height, key.width)
        if self.resize_crop is None:
            return vs
        return dataclasses.replace(vs, views=self.resize_crop(vs.views, key.height, key.width, rng,
                                                              self.describe(key.index)))

    def __getitem__(self, key: SampleKey | int) -> dict:
        if not isinstance(key, SampleKey):
            raise TypeError("index the dataset with a SampleKey (index, height, width, epoch)")
        rng = self.rng(key)
        vs = self.views(key, rng)
        views = vs.views
        for v in views:
            if v.image.shape[:2] != (key.height, key.width):
                raise ValueError(f"{self.describe(key.index)}: view is {v.image.shape[1]}x{v.image.shape[0]}, "
                                 f"the batch needs {key.width}x{key.height} (configure a resize/crop)")
        imgs = torch.stack([torch.from_numpy(np.ascontiguousarray(v.image)).permute(2, 0, 1) for v in views])
        imgs = imgs.float().div_(255.0)
        if self.photometric is not None:
            imgs = self.photometric(imgs, rng)
        ref = views[0]
        projs = stage_projections(np.stack([v.E for v in views]), np.stack([v.K for v in views]))
        if ref.depth is None:  # a photo without depth (self-supervised): nothing for the cross-entropy
            depth, mask = np.zeros((key.height, key.width), np.float32), np.zeros((key.height, key.width), bool)
        else:
            depth = ref.depth.astype(np.float32)
            mask = ref.mask & (depth > 0)
        depth_gt, masks = {}, {}
        for name, s in STAGE_SCALES.items():
            step = round(1 / s)
            depth_gt[name] = torch.from_numpy(np.ascontiguousarray(depth[::step, ::step]))
            masks[name] = torch.from_numpy(np.ascontiguousarray(mask[::step, ::step])).float()
        return {
            "imgs": normalize(imgs),
            "proj_matrices": {k: v[0] for k, v in projs.items()},
            "depth_values": torch.linspace(vs.depth_min, vs.depth_max, self.num_depth, dtype=torch.float32),
            "depth_gt": depth_gt,
            "mask": masks,
            "self_supervised": torch.tensor(float(vs.self_supervised)),
            "pair_id": torch.tensor(int(vs.pair_id)),
        }
