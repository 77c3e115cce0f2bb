"""The network presets: one record per preset, the one place that names them.

A record holds the network's architecture and inference settings (:class:`~.config.ModelConfig`) and
what a run of it defaults to: stage 1's ``--min-parallax``, whether the package ships trained weights for
it (:mod:`.shipped`), whether ``--precision auto`` may take stage 1's attention in bf16, and whether
``reconstruct`` offers it. Every list of preset names (the ``--preset`` choices of ``reconstruct``,
``demo``, ``info`` and ``train``) and every per-preset default is read from :data:`PRESETS`: adding a
preset is one record here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from mvsformerpp.models.config import ModelConfig, architecture


@dataclass(frozen=True)
class NetworkPreset:
    """One named network and the run-time defaults that go with it."""

    name: str
    model: ModelConfig
    """Architecture and inference settings."""
    min_parallax: float = 0.0
    """``reconstruct --min-parallax`` default (:mod:`mvsformerpp.inference.search_range`): stage-1 pixels per
    plane below which a view's search range is widened; 0: off."""
    shipped_weights: bool = False
    """The package ships trained weights for this preset (:mod:`mvsformerpp.models.shipped`); without a
    checkpoint, ``reconstruct`` runs them (else a seeded random initialisation)."""
    attention_bf16: bool = False
    """``--precision auto`` may run stage 1's transformer attention in bf16 inside the fp32 network, on CPUs
    where that was measured faster at no cost in accuracy (:func:`mvsformerpp.utils.precision.attention_in_bf16`)."""
    reconstruct: bool = True
    """Offered by ``reconstruct``, ``demo`` and ``info`` (False: a training preset whose weights run as
    another preset's)."""


PRESETS: dict[str, NetworkPreset] = {p.name: p for p in (
    # Same architecture, much smaller ViT and SVA, trainable backbone (no pretrained weights exist).
    # Stage 1 adds the cost volume's own window-aggregated evidence to its transformer's logits (weight and
    # window chosen on synthetic calibration scenes: docs/model-card.md, "Stage 1's local evidence"), gated
    # by its own peak so that windows with nothing to match (painted walls) add nothing ("Painted walls").
    # Its transformer runs over two placements of its token grid, which halves the 32-pixel block pattern
    # for one more pass (four remove it for three: "Stage 1's token grid in several placements").
    # --min-parallax 0.15 and bf16 attention were chosen by measurements of its shipped weights.
    NetworkPreset("lite", ModelConfig(vit_dim=192, vit_depth=6, vit_heads=3, sva_heads=3, freeze_vit=False,
                                      cvt_layers=2, local_evidence=2.0, local_evidence_box=13,
                                      local_evidence_gate=(1.5, 2.2), cvt_shifts=2),
                  min_parallax=0.15, shipped_weights=True, attention_bf16=True),
    # config/mvsformer++.json of the reference. --min-parallax off: its official weights were not measured
    # with it.
    NetworkPreset("paper", ModelConfig()),
    # BlendedMVS+DTU fine-tuning (mvsformer++_ft.json): the same network and weights layout. Its loss
    # supervises stage 4 only (the reference's ce_loss returns the last stage's loss); the
    # training recipe blended_finetune overrides this with all four stages unless loss_weights is null.
    NetworkPreset("paper_finetune", ModelConfig(loss_weights=(0.0, 0.0, 0.0, 1.0)), reconstruct=False),
)}

PRESET_NAMES: tuple[str, ...] = tuple(PRESETS)
"""Every preset (``train --preset``)."""
RECONSTRUCT_PRESETS: tuple[str, ...] = tuple(name for name, p in PRESETS.items() if p.reconstruct)
"""The presets ``reconstruct``, ``demo`` and ``info`` offer."""


def get_preset(name: str) -> NetworkPreset:
    """The record of preset ``name``; ValueError naming the choices when there is none."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    return PRESETS[name]


def get_config(preset: str = "paper", **overrides) -> ModelConfig:
    """The network configuration of ``preset`` with field overrides."""
    return dataclasses.replace(get_preset(preset).model, **overrides)


def presets_for(config: ModelConfig) -> list[str]:
    """Names of the presets whose weights have the shapes of ``config``'s network (may be empty)."""
    arch = architecture(config)
    return [name for name, preset in PRESETS.items() if architecture(preset.model) == arch]
