"""Training configuration: one documented dataclass, three recipes, YAML in and out, ``--set`` overrides.

``RECIPES`` hold the reference's loss and training settings for DTU training and BlendedMVS
fine-tuning, and a small synthetic recipe for CPU runs, tests and the default model. A YAML file with
any subset of the fields (plus ``recipe:`` to start from one) gives the same config; the resolved
config is saved as ``RUN_DIR/config.yaml``.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import yaml

from mvsformerpp.errors import InputError
from mvsformerpp.models.presets import PRESET_NAMES
from mvsformerpp.utils.config_flags import plain_value


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on (the reference's values in the ``dtu`` recipe)."""

    # ---- what to train on
    recipe: Literal["synthetic", "dtu", "blended_finetune"] = "synthetic"
    """Data source: on-the-fly synthetic scenes, the DTU training layout, or BlendedMVS balanced with DTU."""
    data_root: str | None = None
    """DTU root (``dtu``); BlendedMVS root (``blended_finetune``; DTU then from ``dtu_root``)."""
    dtu_root: str | None = None
    """DTU root mixed into BlendedMVS fine-tuning (``blended_finetune``)."""
    dtu_train_list: str | None = None
    """``blended_finetune``: file listing the DTU scans mixed in (None: the 95-scan training list shipped with
    the package; give one to fine-tune with part of DTU)."""
    dtu_val_list: str | None = None
    """``blended_finetune`` without ``val_list``: file listing the DTU scans validated on (None: the shipped
    test list)."""
    train_list: str | None = None
    """File listing the training scans/scenes (None: the recipe's list shipped with the package)."""
    val_list: str | None = None
    """File listing the validation scans/scenes (None: the recipe's list)."""
    # ---- network
    preset: Literal[PRESET_NAMES] = "lite"
    """Network preset (:data:`mvsformerpp.models.presets.PRESETS`)."""
    init_checkpoint: str | None = field(default=None, metadata={"flag": "--checkpoint", "metavar": "INIT"})
    """Weights to start from (a safetensors checkpoint, an official .pth, or DINOv2 backbone weights)."""
    xavier_init: bool = True
    """Xavier-uniform init of the FMT's linear layers when training from scratch (the official FMT init)."""
    # ---- samples
    num_views: int = field(default=5, metadata={"flag": "--views", "metavar": "N"})
    """Views per sample: the reference and num_views - 1 sources."""
    num_depth: int = 192
    """Depth samples of the range; only its ends reach the network (stage 1 is inverse-uniform)."""
    interval_scale: float = 1.06
    """Scale of the cam files' depth interval (DTU, BlendedMVS)."""
    light_ids: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6)
    """DTU lightings used for training (each makes its own samples)."""
    height: int = 64
    """Training height when ``resolutions`` is empty (a multiple of 32)."""
    width: int = 96
    """Training width when ``resolutions`` is empty."""
    resolutions: tuple[tuple[int, int], ...] = ()
    """Multi-scale (H, W) list cycled batch by batch; empty: ``height`` x ``width`` only."""
    resize_range: tuple[float, float] = (1.0, 1.2)
    """Random enlargement e of the resize before the random crop."""
    resize_min_scale: float = 0.45
    """Lower clip of the resize factor (DTU 0.45, BlendedMVS 0.375)."""
    resize_base: tuple[int, int] | None = None
    """(H0, W0) the resize factor refers to (DTU 1200 x 1600); None: each sample's own size."""
    augment: bool = True
    """Colour jitter and gamma on training samples (same factors for all views of a sample)."""
    val_height: int | None = None
    """Validation height (None: ``height``)."""
    val_width: int | None = None
    """Validation width (None: ``width``)."""
    # ---- synthetic scenes
    synthetic_source: str = "mvsformerpp.synth:random_scene"
    """Scene generator ``module:function`` (see ``mvsformerpp.data.synthetic``)."""
    synthetic_options: dict = field(default_factory=dict)
    """Keyword options passed to the generator."""
    synthetic_train_scenes: int = 2000
    """Training scenes (scene seeds seed_base .. seed_base + n - 1)."""
    synthetic_val_scenes: int = 8
    """Validation scenes (seeds after a gap of 10^6, never seen in training)."""
    synthetic_views_per_scene: int = 7
    """Cameras per synthetic scene (each a reference view once per epoch)."""
    synthetic_scene_batches: bool = False
    """Every view of a synthetic scene is a reference in the same batch, one after the other, and the scene
    is rendered once for all of them: the training order shuffles whole scenes (blocks of
    ``synthetic_views_per_scene`` samples) instead of single samples. Each sample then costs about one
    rendered view instead of ``num_views`` (the renderer sets the pace of a GPU run); a batch holds
    ``batch_size / synthetic_views_per_scene`` scenes, which must be a whole number."""
    synthetic_render_scale: float = 1.2
    """Render at the batch size times this, leaving room for the random resize and crop."""
    synthetic_range_margin: tuple[float, float] = (0.05, 0.05)
    """Depth-range margin of training samples: each end of the reference view's true range is widened by a
    fraction drawn uniformly from this interval (validation: 5 %). Wider draws teach the loose ranges of
    real cam files and sparse points."""
    parallax_range: tuple[float, float] | None = None
    """Declared (low, high) image shift per depth plane at stage 4, in input pixels, that the training
    views cover: a run starts only if the 10th-90th percentiles of sampled views lie inside it
    (:mod:`mvsformerpp.training.parallax`). None: no check."""
    min_overlap: float | None = None
    """Declared least share of the reference's valid pixels that a source view sees (inside its image, in
    front of it), as the median over sampled views: windows cut around different places of a scene
    overlap too little to match. None: no check."""
    parallax_samples: int = 32
    """Training samples the ``parallax_range`` and ``min_overlap`` checks draw."""
    # ---- real photos mixed into synthetic training (mvsformerpp.data.real)
    real_scenes: tuple[str, ...] = field(default=(), metadata={"metavar": "SCENE"})
    """Calibrated real scenes (any layout ``reconstruct`` reads: LLFF, IDR, COLMAP, MVSNet, ...) that make half of
    every synthetic batch, as pairs of references of one scene: supervised by ``real_labels`` and/or
    ``self_supervised_weight`` (one of them is needed). Empty: synthetic scenes only."""
    real_labels: str | None = field(default=None, metadata={"metavar": "LABELS"})
    """Teacher depth maps of the real scenes, ``LABELS/<scene folder>/<view>.pfm`` (``tools/teacher_labels.py``):
    the cross-entropy trains on them where they hold a depth (distillation). None: no labels."""
    self_supervised_weight: float = 0.0
    """Weight of the self-supervised loss (photometric consistency of every stage's expected depth and cross-view
    agreement, :mod:`mvsformerpp.training.self_supervision`) on the real scenes' samples (0: off)."""
    # ---- optimisation
    batch_size: int = 4
    """Global batch (all processes together); the reference: 16 on 4 GPUs."""
    micro_batch: int = 0
    """Samples per forward pass inside a process (gradient accumulation); 0: the whole per-process batch."""
    micro_batch_by_height: tuple[tuple[int, int], ...] = ()
    """(max height, micro-batch) pairs, the first that fits a batch's height wins; else ``micro_batch``."""
    lr: float = 1e-3
    """AdamW learning rate of the trainable parameters."""
    weight_decay: float = 0.0
    """AdamW weight decay. The reference's config says 0.01 but applies it only to a parameter group that
    does not exist while DINOv2 is frozen, so its training runs with none; 0.0 reproduces that."""
    betas: tuple[float, float] = (0.9, 0.999)
    """AdamW betas."""
    warmup_steps: int = 500
    """Linear warm-up from 0 over this many optimiser steps."""
    min_lr_ratio: float = 0.01
    """Cosine decay from 1 down to this fraction of ``lr`` at the last step."""
    epochs: int = 15
    """Epochs (ignored when ``max_steps`` is set)."""
    max_steps: int | None = None
    """Optimiser steps of the run; None: epochs x batches per epoch."""
    loss_weights: tuple[float, float, float, float] | None = None
    """Per-stage weights of the cross-entropy loss; None: the preset's ``loss_weights``."""
    window_guide: float = 0.0
    """Share of the training samples whose stages 2-4 search around the true depth (the window moved at random
    by up to its half-width) instead of the previous stage's estimate: the truth then lies inside every fine
    stage's window, so they train on all pixels, not only where the coarser stages were right (0: the
    reference's training)."""
    cvt_random_placement: bool = False
    """Run stage 1's transformer on its token grid placed at a random whole-cell offset (0-3 cells up and
    left, border cells repeated, the logits cropped back) at every training step, instead of always at the
    volume's corner: no position inside a 4x4-cell patch is then special to the network, and every placement
    that inference averages (``cvt_shifts``) is one it was trained on (False: the reference's training)."""
    cvt_train_shifts: bool = False
    """Train stage 1 on what inference computes: the mean of its transformer's logits over the preset's
    ``cvt_shifts`` placements of the token grid (:meth:`~mvsformerpp.models.cvt.CostVolumeTransformer.
    _shift_averaged`), so the finer stages also train around that estimate (False: one placement, at the
    volume's corner, as the reference trains)."""
    train_stages: int = 4
    """Cascade stages a training step runs and scores (1-4): fewer trains the coarse stages alone at a
    fraction of the cost (the later stages are frozen; validation still runs all four)."""
    trainable: tuple[str, ...] = ()
    """Parameter-name prefixes that train (for example ``["fusions.0"]``: stage 1's cost-volume
    transformer and visibility net); the rest is frozen, its BatchNorm statistics kept. Empty: every
    parameter (but a frozen DINOv2)."""
    grad_clip: float | None = None
    """Clip the gradient norm at this value (None: no clipping, as the reference)."""
    max_bad_steps: int = 20
    """Non-finite losses tolerated (the step is skipped and counted) before the run stops."""
    # ---- execution
    seed: int = 0
    """Seed of the initialisation, the data order and every sample's augmentation."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """Device of each process (under torchrun: cuda:LOCAL_RANK); ``auto``: CUDA when present, else the CPU."""
    precision: Literal["fp32", "bf16", "fp16"] = "fp32"
    """Autocast precision; fp16 uses a gradient scaler."""
    num_workers: int = 0
    """DataLoader worker processes per training process."""
    # ---- validation, logging, checkpoints
    val_every: int = 0
    """Validate every this many steps (0: at the end of every epoch) and at the end of the run."""
    val_samples: int = 32
    """Validation samples (the first ones of the validation split; 0: all)."""
    best_metric: str = "abs_rel"
    """Validation metric that chooses ``best.safetensors`` (lower is better)."""
    log_every: int = 10
    """Write a metrics row every this many steps."""
    save_every: int = field(default=500, metadata={"metavar": "N"})
    """Write ``checkpoints/last.*`` every this many steps (and at the end)."""
    tensorboard: bool = True
    """TensorBoard events in RUN_DIR/tb (needs the ``train`` extra)."""
    progress: bool = True
    """A tqdm bar with loss, lr and samples/s."""

    # ------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return _plain(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, d: dict, base: TrainConfig | None = None) -> TrainConfig:
        """Fields from ``d`` over ``base`` (or the defaults), each converted to its declared type."""
        base = base or cls()
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(f"unknown training config keys {unknown}; known keys: {sorted(known)}")
        hints = typing.get_type_hints(cls)
        return dataclasses.replace(base, **{k: plain_value(v, hints[k], f"training config field {k!r}")
                                            for k, v in d.items()})


# Fields that may change when a run resumes: they do not touch the training trajectory.
RESUMABLE_CHANGES = frozenset({"parallax_range", "min_overlap", "parallax_samples", "num_workers", "val_every",
                               "val_samples", "log_every", "save_every", "tensorboard",
                               "progress", "data_root", "dtu_root"})

# The reference's 25 multi-scale resolutions (512x640 ... 1024x1280, three widths per height from 512 to
# 960, then 1024x1280). Only this range is known, not each width: here the first width of a row is
# 1.25 H rounded half up to a multiple of 64, then +64 and +128, and
# their mean token count (H/8)(W/8) is 12185.6, the n_train of the reference's adaptive attention scaling.
DTU_RESOLUTIONS: tuple[tuple[int, int], ...] = tuple(
    (h, w) for h, w0 in ((512, 640), (576, 704), (640, 832), (704, 896), (768, 960), (832, 1024), (896, 1152),
                         (960, 1216)) for w in (w0, w0 + 64, w0 + 128)) + ((1024, 1280),)

RECIPES: dict[str, TrainConfig] = {
    # Small and fast: CPU runs, tests, the default model.
    "synthetic": TrainConfig(
        recipe="synthetic", preset="lite", height=128, width=160, batch_size=4, lr=1e-3, warmup_steps=100,
        epochs=20, val_samples=16,
    ),
    # The official config/mvsformer++.json: 25 resolutions 512x640 .. 1024x1280, global batch 16 (4 per GPU
    # on 4 GPUs) in micro-batches of 4 up to H = 704 and 2 above, 15 epochs, lr 1e-3, 500 warm-up steps.
    "dtu": TrainConfig(
        recipe="dtu", preset="paper", height=512, width=640,
        resolutions=DTU_RESOLUTIONS,
        resize_base=(1200, 1600), resize_min_scale=0.45, batch_size=16, micro_batch_by_height=((704, 4), (1024, 2)),
        lr=1e-3, warmup_steps=500,
        min_lr_ratio=0.01, epochs=15, val_height=1152, val_width=1536, val_samples=0, best_metric="abs_rel",
        precision="bf16", seed=123, save_every=1000, log_every=50,
    ),
    # config/mvsformer++_ft.json: BlendedMVS + DTU balanced, from a DTU model, lr 1e-4, min_lr 0.005, 10 epochs.
    # loss_weights: all four stages (set loss_weights=[0,0,0,1] for the reference's stage-4-only loss).
    "blended_finetune": TrainConfig(
        recipe="blended_finetune", preset="paper_finetune", height=576, width=768,
        resolutions=DTU_RESOLUTIONS[::-1],
        resize_base=(1536, 2048), resize_min_scale=0.375, batch_size=16, micro_batch_by_height=((704, 4), (1024, 2)),
        lr=1e-4, warmup_steps=500,
        min_lr_ratio=0.005, epochs=10, loss_weights=(1.0, 1.0, 1.0, 1.0), val_samples=0, precision="bf16",
        seed=123, save_every=1000, log_every=50,
    ),
}


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


def parse_overrides(items: list[str]) -> dict:
    """``["key=value", ...]`` (values in YAML: ``lr=1e-4``, ``loss_weights=[0,0,0,1]``) -> dict."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"--set needs key=value, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value) if value.strip() else None
        except yaml.YAMLError as e:
            raise InputError(f"--set {item!r}: the value is not valid YAML ({e})") from e
    return out


def load_config(recipe_or_file: str, overrides: dict | None = None) -> TrainConfig:
    """A recipe name or a YAML file (optionally ``recipe: NAME`` as its base), then ``overrides``."""
    if recipe_or_file in RECIPES:
        config = RECIPES[recipe_or_file]
    else:
        path = Path(recipe_or_file)
        if not path.is_file():
            raise InputError(f"neither a recipe ({', '.join(RECIPES)}) nor a YAML file", path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8-sig")) or {}
        except UnicodeDecodeError as e:
            raise InputError(f"not a YAML text file (byte {e.start} is not UTF-8 text); give a recipe name "
                             f"({', '.join(RECIPES)}) or a YAML file of config fields", path) from e
        except yaml.YAMLError as e:
            raise InputError(f"not valid YAML ({' '.join(str(e).split())})", path) from e
        if not isinstance(data, dict):
            raise InputError("a training config must be a mapping of field: value", path)
        base = RECIPES.get(data.get("recipe", "synthetic"))
        if base is None:
            raise InputError(f"unknown recipe {data.get('recipe')!r}; choose one of {sorted(RECIPES)}", path)
        config = TrainConfig.from_dict(data, base)
    return check_config(TrainConfig.from_dict(overrides or {}, config))


MAX_TRAIN_SIZE = 4096
"""Largest training height or width in pixels."""
MAX_SEED = 2**31 - 1 - 2 * 10_000_000
"""Largest seed: synthetic scene seeds reach seed + 1,000,000 (validation) + the number of scenes
(:data:`MAX_SYNTHETIC_SCENES`), within the renderer's :data:`mvsformerpp.synth.scenes.MAX_SEED`."""
MAX_SYNTHETIC_SCENES = 10_000_000
"""Largest synthetic_train_scenes: an epoch's order is a permutation of all their samples."""
MAX_SCENE_VIEWS = 1000
"""Largest synthetic_views_per_scene."""
MAX_WORKERS = 256
"""Largest num_workers (data-loading processes)."""


def check_config(config: TrainConfig) -> TrainConfig:
    """Reject values the run cannot use, with the field and the fix; returns ``config``."""
    _check_shape(config)
    for name, low, high, low_open in _NUMBERS:
        _check_number(config, name, low, high, low_open)
    if config.recipe == "synthetic":
        _check_synthetic(config)
    _check_options(config)
    if config.recipe == "synthetic":
        _check_synthetic_source(config)
    if config.real_scenes:
        _check_real(config)
    if config.parallax_range is not None and not 0 <= config.parallax_range[0] < config.parallax_range[1]:
        raise InputError(f"parallax_range {list(config.parallax_range)} must be two pixel shifts 0 <= low < high")
    if config.min_overlap is not None and not 0 <= config.min_overlap <= 1:
        raise InputError(f"min_overlap {config.min_overlap} must be a share between 0 and 1")
    if config.parallax_samples < 1:
        raise InputError(f"parallax_samples must be at least 1, got {config.parallax_samples}")
    return config


def _check_shape(config: TrainConfig) -> None:
    """Training sizes, depth planes, views, batches and step counts."""
    sizes = [("height/width", (config.height, config.width))] + [("resolutions", r) for r in config.resolutions]
    if config.val_height or config.val_width:
        sizes.append(("val_height/val_width", (config.val_height or config.height, config.val_width or config.width)))
    for name, (h, w) in sizes:
        if h < 32 or w < 32 or h % 32 or w % 32:
            raise InputError(f"training size {h}x{w} ({name}) must be multiples of 32, e.g. "
                             f"{max(32, -(-h // 32) * 32)}x{max(32, -(-w // 32) * 32)}")
        if max(h, w) > MAX_TRAIN_SIZE:
            raise InputError(f"training size {h}x{w} ({name}) must be at most {MAX_TRAIN_SIZE} pixels per side (a "
                             "sample's activations grow with its pixels: the reference trains at 512x640 to "
                             "1024x1280); use --height/--width or --set resolutions=...")
    if config.num_depth < 2:
        raise InputError(f"num_depth must be at least 2 (the depth planes of a sample's range), got {config.num_depth} "
                         "(--set num_depth=...)")
    if config.num_views < 2:
        raise InputError(f"num_views must be at least 2 (the reference view and a source), got {config.num_views}")
    if config.batch_size < 1:
        raise InputError(f"batch_size must be at least 1, got {config.batch_size} (--batch-size)")
    which, value = ("max_steps", config.max_steps) if config.max_steps is not None else ("epochs", config.epochs)
    if value < 1:
        raise InputError(f"{which} must be at least 1 (a run of no step trains nothing and saves no checkpoint), got "
                         f"{value} (--{which.replace('_', '-')})")
    if not 0 <= config.seed <= MAX_SEED:
        raise InputError(f"seed must be 0 .. {MAX_SEED} (synthetic scenes are drawn from seed + their index, and "
                         f"the renderer's generators take 32-bit seeds), got {config.seed} (--seed)")
    if config.save_every < 1 or config.log_every < 1:
        raise InputError("save_every and log_every must be >= 1")


_NUMBERS = (("lr", 0.0, math.inf, True), ("min_lr_ratio", 0.0, 1.0, False), ("weight_decay", 0.0, math.inf, False),
            ("grad_clip", 0.0, math.inf, True), ("interval_scale", 0.0, math.inf, True),
            ("resize_min_scale", 0.0, 1.0, True), ("synthetic_render_scale", 1.0, 4.0, False),
            ("window_guide", 0.0, 1.0, False), ("self_supervised_weight", 0.0, math.inf, False))
"""(field, low, high, low excluded) of the real-valued fields (None: unset, not checked)."""


def _check_number(config: TrainConfig, name: str, low: float, high: float, low_open: bool) -> None:
    value = getattr(config, name)
    if value is None:
        return
    ok = math.isfinite(value) and (value > low if low_open else value >= low) and value <= high
    if not ok:
        bound = f"{'>' if low_open else '>='} {low:g}" + (f" and <= {high:g}" if math.isfinite(high) else "")
        raise InputError(f"{name} must be a finite number {bound}, got {value!r} (--set {name}=...)")


def _check_synthetic(config: TrainConfig) -> None:
    """The synthetic recipe's scene counts and scene batches."""
    if (max(config.synthetic_train_scenes, config.synthetic_val_scenes) > MAX_SYNTHETIC_SCENES
            or config.synthetic_views_per_scene > MAX_SCENE_VIEWS):
        raise InputError(f"synthetic_train_scenes and synthetic_val_scenes must be at most {MAX_SYNTHETIC_SCENES:,} "
                         f"(every epoch orders all their samples) and synthetic_views_per_scene at most "
                         f"{MAX_SCENE_VIEWS} (each scene lays out its cameras), got {config.synthetic_train_scenes:,}, "
                         f"{config.synthetic_val_scenes:,} and {config.synthetic_views_per_scene:,}")
    if (config.synthetic_train_scenes < 1 or config.synthetic_val_scenes < 1
            or config.synthetic_views_per_scene < config.num_views):
        raise InputError(f"synthetic_train_scenes and synthetic_val_scenes must be >= 1 and synthetic_views_per_scene "
                         f">= num_views ({config.num_views}), got {config.synthetic_train_scenes}, "
                         f"{config.synthetic_val_scenes} and {config.synthetic_views_per_scene}")
    if config.synthetic_scene_batches and config.batch_size % config.synthetic_views_per_scene:
        raise InputError(f"synthetic_scene_batches puts each scene's {config.synthetic_views_per_scene} views "
                         f"(synthetic_views_per_scene) into one batch: batch_size must be a multiple of it, got "
                         f"{config.batch_size} (--batch-size, or --set synthetic_views_per_scene=...)")


def _check_options(config: TrainConfig) -> None:
    """Counts, optimiser settings, loss weights, stages and stage 1's placement options."""
    if config.num_workers > MAX_WORKERS:
        raise InputError(f"num_workers must be at most {MAX_WORKERS} (each is a process rendering samples), got "
                         f"{config.num_workers:,} (--set num_workers=...)")
    for name in ("warmup_steps", "max_bad_steps", "num_workers", "val_samples", "val_every", "micro_batch"):
        if getattr(config, name) < 0:
            raise InputError(f"{name} must be >= 0, got {getattr(config, name)} (--set {name}=...)")
    if not all(0 <= b < 1 for b in config.betas):
        raise InputError(f"betas must be two numbers in [0, 1), got {list(config.betas)}")
    lo, hi = config.resize_range
    if not (math.isfinite(hi) and 0 < lo <= hi):
        raise InputError(f"resize_range must be two numbers 0 < low <= high, got {list(config.resize_range)}")
    if config.loss_weights is not None and not all(math.isfinite(w) and w >= 0 for w in config.loss_weights):
        raise InputError(f"loss_weights must be four numbers >= 0, got {list(config.loss_weights)}")
    if not 1 <= config.train_stages <= 4:
        raise InputError(f"train_stages must be 1, 2, 3 or 4 (the cascade stages trained), got {config.train_stages}")
    if config.cvt_random_placement and config.cvt_train_shifts:
        raise InputError("cvt_random_placement and cvt_train_shifts each choose where stage 1's token grid lies in "
                         "training: set at most one of them true")


def _check_synthetic_source(config: TrainConfig) -> None:
    """The synthetic recipe's generator and its texture library (``synthetic_options: {textures: LIBRARY}``)."""
    # (imported here: the command line reads this module for its flags without torch, which the data needs)
    from mvsformerpp.data.synthetic import resolve_source
    from mvsformerpp.synth.texture_library import read_manifest

    resolve_source(config.synthetic_source)
    if config.synthetic_options.get("textures") is not None:  # a texture library: checked before training
        read_manifest(config.synthetic_options["textures"])


REAL_BLOCK = 4
"""Samples a batch keeps together when real scenes are mixed in: two synthetic samples and a real pair."""


def _check_real(config: TrainConfig) -> None:
    """``real_scenes`` can train: a synthetic recipe, whole pairs per forward pass, a loss, readable scenes."""
    if config.recipe != "synthetic" or config.synthetic_scene_batches:
        raise InputError("real_scenes are mixed into the synthetic recipe without synthetic_scene_batches (every "
                         f"batch: {REAL_BLOCK // 2} synthetic samples and a real pair)")
    if config.batch_size % REAL_BLOCK or (config.micro_batch and config.micro_batch % REAL_BLOCK):
        raise InputError(f"with real_scenes, batch_size and micro_batch must be multiples of {REAL_BLOCK} (a pair of "
                         f"real references stays in one pass), got {config.batch_size} and {config.micro_batch}")
    if config.real_labels is None and config.self_supervised_weight <= 0:
        raise InputError("real_scenes need real_labels (teacher depth maps) or self_supervised_weight > 0")
    # (imported here: the command line reads this module for its flags without torch, which the data needs)
    from mvsformerpp.data.real import load_real_scenes, scene_name

    load_real_scenes(config.real_scenes)
    if config.real_labels is not None:
        labels = Path(config.real_labels)
        found = [scene_name(p) for p in config.real_scenes if any((labels / scene_name(p)).glob("*.pfm"))]
        if not found:
            raise InputError("no teacher depth maps for any real scene (expected LABELS/<scene folder>/<view>.pfm, "
                             "made by tools/teacher_labels.py)", labels)


def dump_config(config: TrainConfig) -> str:
    return yaml.safe_dump(config.to_dict(), sort_keys=False)


def config_differences(old: TrainConfig, new: TrainConfig, ignore=RESUMABLE_CHANGES) -> list[str]:
    """``field: old -> new`` for every field that differs (except ``ignore``)."""
    a, b = old.to_dict(), new.to_dict()
    return [f"{k}: {a[k]!r} -> {b[k]!r}" for k in a if k not in ignore and a[k] != b[k]]
