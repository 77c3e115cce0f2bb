"""The settings of ``reconstruct``: one frozen dataclass, the one definition of every flag of the command.

Each field's type, default and docstring make its flag (:mod:`mvsformerpp.utils.config_flags`); the
field's metadata names the flag where it is not ``--field-name``, and error messages name it the same way
(:func:`config_flag`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

from mvsformerpp.errors import InputError
from mvsformerpp.fusion.choice import Calibration, FusionChoice, check_overrides, choose_fusion
from mvsformerpp.fusion.config import PRESETS as FUSION_PRESETS
from mvsformerpp.io.scene import check_depth_range
from mvsformerpp.models.config import INFERENCE_SETTINGS, ModelConfig
from mvsformerpp.models.presets import PRESETS, RECONSTRUCT_PRESETS, get_config
from mvsformerpp.pipelines.sfm import SfMConfig
from mvsformerpp.utils.config_flags import flag_name

NETWORK, RUN = "network", "reconstruction"

FUSION_CHOICES = tuple(FUSION_PRESETS)
"""The fusion presets (:data:`mvsformerpp.fusion.config.PRESETS`)."""


@dataclass(frozen=True)
class ReconstructConfig:
    """Everything that decides the result of ``reconstruct``; saved to ``OUT/config.json``."""

    preset: Literal[RECONSTRUCT_PRESETS] = field(default="lite", metadata={"group": NETWORK})
    """Network preset: ``lite`` is a small network for the CPU with trained weights shipped in the package,
    ``paper`` the official MVSFormer++ network (with ``--checkpoint model_best.pth``)."""
    checkpoint: str | None = field(default=None, metadata={"group": NETWORK, "metavar": "PATH"})
    """Weights matching the preset (default: the shipped weights for ``lite``; ``paper`` has none, so
    without a checkpoint its network is randomly initialised)."""
    device: str = field(default="cpu", metadata={"group": NETWORK})
    """Torch device: cpu, cuda, cuda:1, ..."""
    precision: Literal["auto", "fp32", "bf16", "fp16"] = field(default="auto", metadata={"group": NETWORK})
    """Precision of the network: ``auto`` is fp32, with stage 1's transformer attention in bf16 for the
    ``lite`` network on CPUs with AMX, where that is faster at no measured cost in accuracy; ``fp32`` is
    fp32 throughout; ``bf16``/``fp16`` run the network under autocast (bf16 is the reference's GPU setting;
    cost volumes stay fp32)."""
    backend: Literal["torch", "onnxruntime", "auto"] = field(default="torch", metadata={"group": NETWORK})
    """What runs the network: ``torch`` (PyTorch), ``onnxruntime`` (the network exported as ONNX graphs: see
    --onnx-model; fp32, CPU or onnxruntime's CUDA provider), or ``auto``: onnxruntime where it was measured
    clearly faster than PyTorch for the preset and device (bench/bench_onnx.py), else torch."""
    onnx_model: str | None = field(default=None, metadata={"group": NETWORK, "metavar": "DIR"})
    """The exported model onnxruntime runs (``mvsformerpp export-onnx``; it must hold the run's weights, views
    and temperatures); default: the run's network exported on first use into OUT/onnx and kept there."""
    max_size: int | None = field(default=1536, metadata={"group": RUN, "metavar": "PX"})
    """Cap on the longer side of the working resolution (images are never upscaled and the aspect ratio
    is kept)."""
    memory_gb: float | None = field(default=None, metadata={"group": RUN, "metavar": "GB"})
    """Memory budget of one forward pass and of fusion, which streams the depth maps through a cache of
    this size (default: half of the free memory)."""
    num_views: int = field(default=5, metadata={"flag": "--views", "group": RUN, "metavar": "N"})
    """Views per depth map: the reference plus N-1 best neighbours (the reference uses 5 on DTU)."""
    depth_range: tuple[float, float] | None = field(default=None,
                                                    metadata={"group": RUN, "metavar": ("MIN", "MAX")})
    """Override of every view's depth range (scene units)."""
    depth_format: Literal["auto", "interval", "max"] = field(default="auto", metadata={"group": RUN})
    """How a two-number depth line of an MVSNet cam file is read: MIN INTERVAL, MIN MAX, or auto (MAX when
    the second number is larger)."""
    max_images: int | None = field(default=None, metadata={"group": RUN, "metavar": "N"})
    """Use only N overlapping views: the first view and its best neighbours (quick looks, tests)."""
    interval_scale: float = field(default=1.0, metadata={"group": RUN, "metavar": "S"})
    """Widen each view's depth range from its minimum by S (the reference's interval_scale for ranges given
    as MIN INTERVAL; the paper's DTU and Tanks-and-Temples runs use 1.06); not applied to ``--depth-range``."""
    num_depth: int = field(default=192, metadata={"group": RUN, "metavar": "N"})
    """Depth planes of the input range, written to the output cams (the cascade uses only the ends of the
    range)."""
    temperatures: tuple[float, ...] = field(default=ModelConfig.temperatures,
                                            metadata={"group": RUN, "metavar": "T", "nargs": 4})
    """Per-stage softmax temperatures of the depth readout (the paper's: 5 5 5 1)."""
    cvt_shifts: int | None = field(default=None, metadata={"group": NETWORK, "metavar": "K"})
    """Placements of stage 1's transformer token grid whose logits are averaged, 1-4 (default: the
    preset's: 2 for lite, 1 (the reference's) for paper): each placement's 32-pixel patches leave a
    block pattern in the depth maps that the others cancel; each one costs a pass of that transformer."""
    min_parallax: float | None = field(default=None, metadata={"group": NETWORK, "metavar": "PX"})
    """Least image shift, in stage-1 pixels summed over the source views, between stage 1's neighbouring
    depth planes: a view whose depth range is too tight for its cameras' baselines is searched over a
    range widened until its planes move the images that much (default: the preset's: 0.15 for lite,
    0 (the ranges as given, as the reference) for paper; 0 turns it off)."""
    fusion: Literal[FUSION_CHOICES + ("none",)] = field(default="normal", metadata={"group": RUN})
    """Fusion preset (dtu, tnt_intermediate and tnt_advanced are the paper's settings, see
    ``mvsformerpp fuse``); none writes the depth maps only (fuse later with ``mvsformerpp fuse``)."""
    fusion_conf: float | None = field(default=None, metadata={"flag": "--conf", "group": RUN, "metavar": "C"})
    """Fusion confidence threshold in [0, 1) (default: the one calibrated for the default weights when they
    run, else the preset's)."""
    fusion_disp: float | None = field(default=None, metadata={"flag": "--disp", "group": RUN, "metavar": "PX"})
    """Fusion: reprojection error in pixels (normal) or disparity difference, f * baseline / depth (gipuma)
    (default: the preset's)."""
    fusion_num_consistent: int | None = field(default=None, metadata={"flag": "--num-consistent", "group": RUN,
                                                                      "metavar": "N"})
    """Fusion (normal and gipuma): consistent source views needed to keep a pixel (default: the preset's)."""
    fusion_num_src_views: int | None = field(default=None, metadata={"flag": "--num-src-views", "group": RUN,
                                                                     "metavar": "N"})
    """Fusion: source views checked per reference view, its best neighbours (default: the preset's)."""
    fusion_resolution: Literal["working", "original"] = field(default="working", metadata={"group": RUN})
    """Size of the depth maps fusion reads: working, the resolution they were computed at (photos larger
    than it do not multiply the points or the fusion time), or original, the maps as written."""
    mask_dir: str | None = field(default=None, metadata={"group": RUN, "metavar": "DIR"})
    """Object masks applied before fusion: one per photo, named like it or by view index (DTU's
    mask/000.png and BlendedMVS's _masked.jpg are recognised)."""
    output_resolution: Literal["original", "working"] = field(default="original", metadata={"group": RUN})
    """Size of the depth and confidence maps: each photo's own (upsampled from the working resolution), or
    the working resolution with images/ and cams/ scaled to match (smaller files, no upsampling)."""
    cache_mb: int = field(default=2048, metadata={"group": RUN, "metavar": "MIB"})
    """Per-image feature cache budget in MiB; 0 recomputes every image's features for every reference view."""
    sfm: SfMConfig = field(default=SfMConfig(), metadata={"nested": True})
    """Structure-from-motion settings, used when INPUT is a folder of photos."""
    seed: int = field(default=0, metadata={"flag": None})
    """Seed of the random initialisation when no checkpoint is given (keeps resumed runs consistent)."""

    def __post_init__(self) -> None:
        if self.num_views < 2:
            raise InputError(f"{config_flag('num_views')} must be at least 2 (the reference and one source view), "
                             f"got {self.num_views}")
        if self.num_depth < 2:
            raise InputError(f"{config_flag('num_depth')} must be at least 2, got {self.num_depth}")
        if self.max_size is not None and self.max_size < 64:
            raise InputError(f"{config_flag('max_size')} must be at least 64 pixels, got {self.max_size}")
        if self.max_images is not None and self.max_images < 2:
            raise InputError(f"{config_flag('max_images')} must be at least 2, got {self.max_images}")
        if self.memory_gb is not None and not (math.isfinite(self.memory_gb) and self.memory_gb > 0):
            raise InputError(f"{config_flag('memory_gb')} must be a positive number of GB, got {self.memory_gb}")
        if self.cache_mb < 0:
            raise InputError(f"{config_flag('cache_mb')} must be >= 0, got {self.cache_mb}")
        if self.depth_range is not None:
            if not (0 < self.depth_range[0] < self.depth_range[1] and math.isfinite(self.depth_range[1])):
                raise InputError(f"{config_flag('depth_range')} {self.depth_range[0]:g} {self.depth_range[1]:g} must "
                                 "satisfy 0 < min < max")
            check_depth_range(*self.depth_range, config_flag("depth_range"))
        if self.depth_format not in ("auto", "interval", "max"):
            raise InputError(f"{config_flag('depth_format')} must be auto, interval or max, got {self.depth_format!r}")
        if not (math.isfinite(self.interval_scale) and self.interval_scale > 0):
            raise InputError(f"{config_flag('interval_scale')} must be a positive number, got {self.interval_scale}")
        check_overrides(**fusion_overrides(self), conf=self.fusion_conf)
        if self.cvt_shifts is not None and not 1 <= self.cvt_shifts <= 4:
            raise InputError(f"{config_flag('cvt_shifts')} must be 1, 2, 3 or 4 placements of the token grid, "
                             f"got {self.cvt_shifts}")
        if self.min_parallax is not None and not (math.isfinite(self.min_parallax) and 0 <= self.min_parallax <= 4):
            raise InputError(f"{config_flag('min_parallax')} must be between 0 (off) and 4 stage-1 pixels per plane, "
                             f"got {self.min_parallax}")
        if self.onnx_model is not None and self.backend == "torch":
            raise InputError(f"{config_flag('onnx_model')} is run by onnxruntime: add {config_flag('backend')} "
                             "onnxruntime")
        if self.backend == "onnxruntime" and self.precision in ("bf16", "fp16"):
            raise InputError(f"{config_flag('backend')} onnxruntime runs the exported graphs in fp32: use "
                             f"{config_flag('precision')} fp32 (or auto), or {config_flag('backend')} torch for "
                             f"{self.precision}")
        if len(self.temperatures) != 4:
            raise InputError(f"{config_flag('temperatures')} needs one value per stage (4), got {self.temperatures}")
        if not all(math.isfinite(t) and t > 0 for t in self.temperatures):
            raise InputError(f"{config_flag('temperatures')} must be four positive numbers (the official runs use "
                             "5 5 5 1), got " + " ".join(f"{t:g}" for t in self.temperatures))

    def fusion_choice(self, calibrated: Calibration | None) -> FusionChoice | None:
        """The fusion this run does of depth maps made by weights with the ``calibrated`` thresholds
        (:func:`~mvsformerpp.fusion.choice.choose_fusion`); None with ``--fusion none``."""
        if self.fusion == "none":
            return None
        return choose_fusion(self.fusion, calibrated, self.fusion_conf, **fusion_overrides(self))

    @property
    def stage1_min_parallax(self) -> float:
        """``min_parallax`` with the preset's default resolved."""
        if self.min_parallax is not None:
            return float(self.min_parallax)
        return PRESETS[self.preset].min_parallax

    def network_config(self) -> ModelConfig:
        """The preset's network configuration with the settings of this run that change it."""
        return get_config(self.preset, **({} if self.cvt_shifts is None else {"cvt_shifts": self.cvt_shifts}))

    def network_settings(self) -> dict:
        """The run-time settings of this run's network that change its depth maps but not its weights (stage 1's
        local evidence and token-grid placements): part of each view's fingerprint, so that a resumed run
        redoes the views made with other settings, also when a new version of the package changes a preset's."""
        model = self.network_config().to_dict()
        return {k: model[k] for k in INFERENCE_SETTINGS}

    def result_settings(self) -> dict:
        """The fields that change the depth maps (not device or cache size, which only change speed; the
        network's settings, ``cvt_shifts`` with its preset default resolved, are :meth:`network_settings`;
        ``min_parallax`` is given resolved)."""
        d = dataclasses.asdict(self)
        d["min_parallax"] = self.stage1_min_parallax
        for k in ("device", "memory_gb", "cache_mb", "fusion", "fusion_conf", "fusion_disp", "fusion_num_consistent",
                  "fusion_num_src_views", "fusion_resolution", "mask_dir", "sfm", "cvt_shifts", "backend",
                  "onnx_model"):  # (SfM: cameras; the backend: the weights' identity, models.weights)
            d.pop(k)
        return d


def fusion_overrides(settings) -> dict:
    """The fusion settings besides the threshold (None: the preset's) as
    :class:`~mvsformerpp.fusion.FusionConfig` fields, from a :class:`ReconstructConfig` or from the parsed
    flags of its fusion fields (``fuse`` shares them)."""
    return {"disp_threshold": settings.fusion_disp, "num_consistent": settings.fusion_num_consistent,
            "num_src_views": settings.fusion_num_src_views}


def config_flag(name: str) -> str:
    """The command-line flag of a :class:`ReconstructConfig` field (nested SfM settings: their flags joined
    by ``/``)."""
    f = next(f for f in dataclasses.fields(ReconstructConfig) if f.name == name)
    if f.metadata.get("nested"):
        return "/".join(flag_name(SfMConfig, g.name) for g in dataclasses.fields(SfMConfig)
                        if g.metadata.get("flag", "") is not None)
    return flag_name(ReconstructConfig, name)
