"""The training and validation datasets of a :class:`TrainConfig`."""

from __future__ import annotations

from mvsformerpp.data import MVSDataset, PhotometricAugment, ResizeCrop, SyntheticDataset
from mvsformerpp.training.config import TrainConfig

# Validation scenes of the synthetic recipe start this far after the training seeds.
SYNTHETIC_VAL_OFFSET = 1_000_000


def build_datasets(config: TrainConfig) -> tuple[MVSDataset, MVSDataset]:
    """(train, validation) for the config's recipe; validation has no augmentation and a centre-ish crop."""
    train_tf = ResizeCrop(config.resize_base, tuple(config.resize_range), config.resize_min_scale)
    photometric = PhotometricAugment() if config.augment else None
    # Validation: the fixed scale e = 1 and the crop drawn from a generator seeded per sample.
    val_tf = ResizeCrop(config.resize_base, (1.0, 1.0), config.resize_min_scale)
    common = dict(num_depth=config.num_depth)
    if config.recipe == "synthetic":
        syn = dict(num_views=config.num_views, views_per_scene=config.synthetic_views_per_scene,
                   source=config.synthetic_source, options=config.synthetic_options,
                   render_scale=config.synthetic_render_scale)
        train = SyntheticDataset(config.synthetic_train_scenes, scene_seed=config.seed, seed=config.seed,
                                 resize_crop=train_tf, photometric=photometric, **syn, **common)
        val = SyntheticDataset(config.synthetic_val_scenes, scene_seed=config.seed + SYNTHETIC_VAL_OFFSET,
                               seed=config.seed + 1, resize_crop=val_tf, **syn, **common)
        return train, val
    raise NotImplementedError(f"recipe {config.recipe!r} is not available yet")
