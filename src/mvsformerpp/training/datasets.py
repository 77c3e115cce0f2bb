"""The training and validation datasets of a :class:`TrainConfig`."""

from __future__ import annotations

from pathlib import Path

from mvsformerpp.data import MVSDataset, PhotometricAugment, ResizeCrop, SyntheticDataset
from mvsformerpp.data.dtu import blended_entries, dtu_entries, dtu_list, read_list
from mvsformerpp.data.real import RealSceneDataset, load_real_scenes
from mvsformerpp.data.scenes import BalancedMix, SceneDataset
from mvsformerpp.errors import InputError
from mvsformerpp.training.config import TrainConfig

# BlendedMVS: photos 1536 x 2048, resize clipped at 0.375 (the reference's values).
BLENDED_BASE, BLENDED_MIN_SCALE = (1536, 2048), 0.375

# Validation scenes of the synthetic recipe start this far after the training seeds.
SYNTHETIC_VAL_OFFSET = 1_000_000


def build_datasets(config: TrainConfig) -> tuple[MVSDataset, MVSDataset]:
    """(train, validation) for the config's recipe; validation has no augmentation and a centre-ish crop."""
    train_tf = ResizeCrop(config.resize_base, tuple(config.resize_range), config.resize_min_scale)
    photometric = PhotometricAugment() if config.augment else None
    # Validation: the fixed scale e = 1 and a centre crop.
    val_tf = ResizeCrop(config.resize_base, (1.0, 1.0), config.resize_min_scale, center=True)
    common = dict(num_depth=config.num_depth)
    if config.recipe == "synthetic":
        syn = dict(num_views=config.num_views, views_per_scene=config.synthetic_views_per_scene,
                   source=config.synthetic_source, options=config.synthetic_options,
                   render_scale=config.synthetic_render_scale)
        train = SyntheticDataset(config.synthetic_train_scenes, scene_seed=config.seed, seed=config.seed,
                                 range_margin=tuple(config.synthetic_range_margin),
                                 resize_crop=train_tf, photometric=photometric, **syn, **common)
        val = SyntheticDataset(config.synthetic_val_scenes, scene_seed=config.seed + SYNTHETIC_VAL_OFFSET,
                               seed=config.seed + 1, resize_crop=val_tf, **syn, **common)
        if config.real_scenes:
            train = BalancedMix([train, real_dataset(config, photometric)])
        return train, val
    scene_kw = dict(num_views=config.num_views, **common)
    depth_kw = dict(num_depth=config.num_depth, interval_scale=config.interval_scale)

    def dtu(root, list_path, tf, photometric, seed, lights=config.light_ids):
        if root is None:
            how = "--data-root" if config.recipe == "dtu" else "--set dtu_root=DIR"
            raise InputError(f"the {config.recipe} recipe needs the DTU root ({how})")
        entries = dtu_entries(root, read_list(list_path), tuple(lights), list_path=list_path, **depth_kw)
        return SceneDataset(entries, resize_crop=tf, photometric=photometric, seed=seed, **scene_kw)

    if config.recipe == "dtu":
        train = dtu(config.data_root, config.train_list or dtu_list("trainval"), train_tf, photometric, config.seed)
        # the reference selects its checkpoint on the test scans; --val-list val.txt is the clean choice
        val = dtu(config.data_root, config.val_list or dtu_list("test"), val_tf, None, config.seed + 1, lights=(3,))
        return train, val
    if config.recipe == "blended_finetune":
        if config.data_root is None:
            raise InputError("the blended_finetune recipe needs the BlendedMVS root (--data-root)")
        root = Path(config.data_root)
        if not root.is_dir():
            raise InputError("BlendedMVS data root not found (give it with --data-root)", root)
        val_scenes = read_list(config.val_list) if config.val_list else []
        scenes = read_list(config.train_list) if config.train_list else sorted(
            p.name for p in root.iterdir() if p.is_dir() and p.name not in val_scenes)
        b_train_tf = ResizeCrop(BLENDED_BASE, tuple(config.resize_range), BLENDED_MIN_SCALE)
        blended = SceneDataset(blended_entries(root, scenes, list_path=config.train_list, **depth_kw),
                               resize_crop=b_train_tf, photometric=photometric, seed=config.seed, **scene_kw)
        train = BalancedMix([blended, dtu(config.dtu_root, config.dtu_train_list or dtu_list("trainval"), train_tf,
                                          photometric, config.seed)])
        if val_scenes:
            val = SceneDataset(blended_entries(root, val_scenes, list_path=config.val_list, **depth_kw),
                               resize_crop=ResizeCrop(BLENDED_BASE, (1.0, 1.0), BLENDED_MIN_SCALE, center=True),
                               seed=config.seed + 1, **scene_kw)
        else:
            val = dtu(config.dtu_root, config.dtu_val_list or dtu_list("test"), val_tf, None, config.seed + 1,
                      lights=(3,))
        return train, val
    raise InputError(f"unknown recipe {config.recipe!r}")


def real_dataset(config: TrainConfig, photometric: PhotometricAugment | None) -> RealSceneDataset:
    """The real scenes of ``config.real_scenes`` as training samples: whole photos (resized to the batch's
    size times 1-1.2, then cropped), so the views of a pair overlap; their teacher labels and whether the
    self-supervised loss scores them."""
    real_tf = ResizeCrop(None, tuple(config.resize_range), 0.0, require_valid=False)
    return RealSceneDataset(load_real_scenes(config.real_scenes), num_views=config.num_views,
                            labels=config.real_labels, self_supervised=config.self_supervised_weight > 0,
                            resize_crop=real_tf, photometric=photometric, seed=config.seed + 2,
                            num_depth=config.num_depth)
