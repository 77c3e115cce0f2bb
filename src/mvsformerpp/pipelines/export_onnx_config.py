"""The settings of ``export-onnx``: one frozen dataclass, the one definition of the command's flags
(:mod:`mvsformerpp.utils.config_flags`); saved in ``model.json``.

The network it exports is the one ``reconstruct`` would run with the same preset, checkpoint, views,
temperatures and stage-1 settings (:meth:`OnnxExportConfig.network_config`), with the weights that
:func:`mvsformerpp.models.weights.weights_for` decides for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from mvsformerpp.errors import InputError
from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.presets import RECONSTRUCT_PRESETS
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.utils.config_flags import flag_name

MIN_OPSET = 17
"""The oldest ONNX opset the graphs can be written in: LayerNormalization came with 17, GridSample with 16."""
MAX_VIEWS = 10
NETWORK_FIELDS = ("preset", "checkpoint", "num_views", "temperatures", "cvt_shifts", "seed")
"""The settings export-onnx shares with reconstruct: they decide the network and its weights."""


@dataclass(frozen=True)
class OnnxExportConfig:
    """The settings of ``export-onnx``; saved in ``model.json``."""

    preset: Literal[RECONSTRUCT_PRESETS] = "lite"
    """Network preset (those of reconstruct): ``lite`` (the weights shipped in the package unless --checkpoint)
    or ``paper`` (the official MVSFormer++ network, with --checkpoint model_best.pth)."""
    checkpoint: str | None = field(default=None, metadata={"metavar": "PATH"})
    """Weights matching the preset (default: the shipped weights where the preset has them; otherwise the
    network is randomly initialised, as in reconstruct)."""
    num_views: int = field(default=5, metadata={"flag": "--views", "metavar": "N"})
    """Views per depth map the view-set graph takes (the reference and N-1 sources), 2 to 10; reconstruct
    --backend onnxruntime runs it with --views N."""
    opset: int = field(default=18, metadata={"metavar": "K"})
    """ONNX opset of the graphs (at least 17)."""
    temperatures: tuple[float, ...] = field(default=ModelConfig.temperatures,
                                            metadata={"metavar": "T", "nargs": 4})
    """Per-stage softmax temperatures of the depth readout, baked into the graph (reconstruct's default)."""
    cvt_shifts: int | None = field(default=None, metadata={"metavar": "K"})
    """Placements of stage 1's transformer token grid (default: the preset's), baked into the graph."""
    stage_outputs: bool = False
    """Also output every stage's depth, confidence, logits and hypotheses."""
    seed: int = field(default=0, metadata={"flag": None})
    """Seed of the random initialisation when no checkpoint is given (reconstruct's)."""

    def __post_init__(self) -> None:
        if not 2 <= self.num_views <= MAX_VIEWS:
            raise InputError(f"{flag_name(OnnxExportConfig, 'num_views')} must be between 2 and {MAX_VIEWS}, "
                             f"got {self.num_views}")
        if self.opset < MIN_OPSET:
            raise InputError(f"--opset {self.opset} is too old for this network: its graphs need LayerNormalization "
                             f"(opset 17) and GridSample (opset 16); use --opset {MIN_OPSET} or later (default 18)")
        # the network's own settings are checked as reconstruct checks them
        self.network_config()

    def network_config(self) -> ReconstructConfig:
        """The network these settings export, as ``reconstruct`` would build and run it."""
        shared = {k: getattr(self, k) for k in NETWORK_FIELDS}
        return ReconstructConfig(**{**shared, "temperatures": tuple(self.temperatures)}, device="cpu",
                                 precision="fp32")

    @classmethod
    def for_run(cls, config: ReconstructConfig) -> OnnxExportConfig:
        """The export of the network ``reconstruct`` runs with ``config``."""
        return cls(**{k: getattr(config, k) for k in NETWORK_FIELDS})
