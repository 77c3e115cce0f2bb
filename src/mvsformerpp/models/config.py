"""Network configuration: one frozen dataclass of every hyper-parameter (the named presets: :mod:`.presets`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass


@dataclass(frozen=True)
class ModelConfig:
    """Every hyper-parameter of the network; ``paper`` is config/mvsformer++.json of the reference."""

    vit_dim: int = 768
    """DINOv2 embedding width (ViT-B/14: 768)."""
    vit_depth: int = 12
    """Number of DINOv2 blocks; SVA taps every depth/3 blocks."""
    vit_heads: int = 12
    vit_patch: int = 14
    vit_img_size: int = 518
    """Pre-training image size: sets the 37x37 positional-embedding grid."""
    vit_rescale: float = 0.4375
    """DINOv2 input = image x 7/16, so a 14-px patch covers 32 input pixels."""
    freeze_vit: bool = True
    """Frozen backbone (pre-trained weights); the lite preset trains its small ViT."""
    sva_heads: int = 12
    """Heads of Side View Attention on DINOv2 tokens (width = vit_dim)."""
    sva_prev_value: float = 0.5
    feat_chs: tuple[int, int, int, int] = (8, 16, 32, 64)
    """FPN channels at 1/1, 1/2, 1/4, 1/8."""
    fmt_heads: int = 4
    fmt_layers: tuple[str, ...] = ("self", "cross", "self", "cross")
    groups: int = 8
    """Group-wise correlation groups at every stage."""
    num_hypotheses: tuple[int, int, int, int] = (32, 16, 8, 4)
    hypothesis_ratio: tuple[float, float, float, float] = (4.0, 2.67, 1.5, 1.0)
    """Half-width of the stage-s window in previous inverse-depth steps (entry 0 unused)."""
    cvt_dim: int = 64
    cvt_heads: int = 4
    cvt_layers: int = 6
    cvt_patch: tuple[int, int, int] = (2, 4, 4)
    cvt_train_avg_tokens: int = 12185
    """n_train of adaptive attention scaling."""
    local_evidence: float = 0.0
    """Weight of stage 1's local matching evidence (:func:`~mvsformerpp.models.cvt.local_evidence`) added to
    the cost-volume transformer's logits; 0: the reference's stage 1 (no weights depend on it)."""
    local_evidence_box: int = 9
    """Side, in stage-1 cells (8 photo pixels), of the square window that aggregates that evidence."""
    local_evidence_gate: tuple[float, float] | None = None
    """(a, b): each cell's evidence is scaled by clip((z_max - a) / (b - a), 0, 1), z_max its largest
    standardised value over the hypotheses, so that a window that matches nothing distinctly (a painted
    wall) adds nothing; None: ungated (bounds chosen on painted walls, the DTU pair and the calibration scenes:
    docs/model-card.md, "Painted walls")."""
    cvt_shifts: int = 1
    """Stage 1's transformer at inference: the mean of its logits over this many placements of its token
    grid, shifted along the diagonal by patch/k cells each (k = 4: 0, 1, 2, 3 cells), so that no patch border
    stays where the other passes have one (:class:`~mvsformerpp.models.cvt.CostVolumeTransformer`); 1: one
    pass, as the reference (and always in training)."""
    temperatures: tuple[float, float, float, float] = (5.0, 5.0, 5.0, 1.0)
    """Inference temperature per stage."""
    loss_weights: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    """Per-stage weights of the training loss (``dlossw``); training configs may override them."""
    attention_backend: str = "sdpa"
    """Softmax attention kernel: sdpa | flash | eager | auto."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        names = {f.name: f for f in dataclasses.fields(cls)}
        unknown = set(d) - set(names)
        if unknown:
            raise ValueError(f"unknown model config keys {sorted(unknown)}")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**kw)


# Fields that change the depth maps of a trained network at inference, not which weights fit it.
INFERENCE_SETTINGS = ("local_evidence", "local_evidence_box", "local_evidence_gate", "cvt_shifts")
# Fields that change only how a network runs or trains, not which weights fit it.
_NON_ARCHITECTURE = ("attention_backend", "temperatures", "loss_weights", "freeze_vit", *INFERENCE_SETTINGS)


def architecture(config: ModelConfig) -> dict:
    """The fields of ``config`` that decide the shapes of the weights."""
    return {k: v for k, v in config.to_dict().items() if k not in _NON_ARCHITECTURE}
