"""Stage 3 of ``reconstruct``: the network of the run's preset and settings, with the run's weights.

Which weights run is decided once (:func:`mvsformerpp.models.weights.weights_for`); this module adds the
preset's network as ``reconstruct``'s settings change it.
"""

from __future__ import annotations

import torch

from mvsformerpp.models.config import INFERENCE_SETTINGS, ModelConfig
from mvsformerpp.models.presets import get_config
from mvsformerpp.models.weights import Weights, weights_for
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig


def run_weights(config: ReconstructConfig) -> Weights:
    """The weights a ``reconstruct`` run with ``config`` runs."""
    return weights_for(config.preset, config.checkpoint, config.seed)


def build_network(config: ReconstructConfig, weights: Weights | None = None) -> torch.nn.Module:
    """The preset's network on the configured device with ``weights`` (default: :func:`run_weights`), in
    evaluation mode."""
    weights = weights or run_weights(config)
    return weights.build(network_config(config)).to(torch.device(config.device)).eval()


def network_config(config: ReconstructConfig) -> ModelConfig:
    """The preset's network configuration with the settings ``config`` changes."""
    return get_config(config.preset, **({} if config.cvt_shifts is None else {"cvt_shifts": config.cvt_shifts}))


def network_settings(config: ReconstructConfig) -> dict:
    """The run-time settings of the network ``build_network(config)`` builds that change its depth maps but
    not its weights (stage 1's local evidence and token-grid placements): part of each view's fingerprint,
    so that a resumed run redoes the views made with other settings, also when a new version of the
    package changes a preset's."""
    model = network_config(config).to_dict()
    return {k: model[k] for k in INFERENCE_SETTINGS}
