"""The MVSFormer++ network (Cao, Ren, Fu, ICLR 2024): tensors in, per-stage depth out."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.models import prepared
from mvsformerpp.models.config import ModelConfig
from mvsformerpp.models.cost_volume import StageNet
from mvsformerpp.models.cvt import CVTAttention, frustum_coordinates
from mvsformerpp.models.dinov2 import DinoVisionTransformer
from mvsformerpp.models.features import ImageFeatures, decode_views, encode_images
from mvsformerpp.models.fmt import FMTWithPathway
from mvsformerpp.models.fpn import FPNDecoder, FPNEncoder
from mvsformerpp.models.hypotheses import initial_hypotheses, plane_step, refined_hypotheses
from mvsformerpp.models.presets import get_config
from mvsformerpp.models.sva import SideViewAttention


class MVSFormerPP(nn.Module):
    """MVSFormer++. Attribute names match the reference so official checkpoints load strictly.

    The attributes and the paper's components (Cao, Ren, Fu, ICLR 2024):

    * ``vit``: the frozen DINOv2 ViT-B/14 backbone (paper sec. 3.1); ``encode_images`` runs it and the
      ``encoder``, the CNN feature pyramid (FPN) down to 1/8 (sec. 3.1).
    * ``decoder_vit``: Side View Attention (SVA, sec. 3.2) on the DINOv2 tokens, the reference's
      ``CrossVITDecoder`` (:class:`~mvsformerpp.models.sva.SideViewAttention`), added to the 1/8 map.
    * ``decoder``: the FPN's top-down pathway: per-stage features at 1/8, 1/4, 1/2, 1/1.
    * ``FMT_module``: the feature matching transformer on the 1/8 features with its pathway to the finer
      stages, the second half of SVA in the paper (sec. 3.2, the reference's ``FMT_with_pathway``).
    * ``fusions``: the four cascade stages (sec. 3.3), each a :class:`~mvsformerpp.models.cost_volume.StageNet`:
      group-wise correlation cost volume with visibility weights (``vis``), then ``cost_reg``: the Cost
      Volume Transformer with frustoconical positional encoding and adaptive attention scaling (CVT,
      sec. 3.3-3.4) at stage 1, 3-D U-Nets at stages 2-4.

    Inference: call :meth:`prepare_for_inference` once (see :mod:`mvsformerpp.models.prepared`).
    The frustoconical positional encoding normalises its coordinates by the depth range of the whole
    batch (``depth_values.min()``/``max()``), as the reference does: a sample's stage-1 output depends
    on the other samples' depth ranges, so batch only views with the same range.
    """

    def __init__(self, config: ModelConfig | None = None):
        super().__init__()
        self.config = cfg = config or ModelConfig()
        self.encoder = FPNEncoder(cfg.feat_chs)
        self.decoder = FPNDecoder(cfg.feat_chs)
        self.vit = DinoVisionTransformer(
            cfg.vit_dim, cfg.vit_depth, cfg.vit_heads, 4.0, cfg.vit_patch, cfg.vit_img_size
        )
        self.decoder_vit = SideViewAttention(cfg.vit_dim, cfg.sva_heads, 3, cfg.feat_chs[3], 4.0, cfg.sva_prev_value)
        self.FMT_module = FMTWithPathway(cfg.feat_chs[3], cfg.fmt_heads, cfg.fmt_layers, cfg.feat_chs[0])
        cvt = dict(mid_ch=cfg.cvt_dim, num_heads=cfg.cvt_heads, num_layers=cfg.cvt_layers, patch=cfg.cvt_patch,
                   train_avg_tokens=cfg.cvt_train_avg_tokens, local_weight=cfg.local_evidence,
                   local_box=cfg.local_evidence_box, local_gate=cfg.local_evidence_gate,
                   shifts=cfg.cvt_shifts)
        self.fusions = nn.ModuleList(
            [StageNet(n, cfg.groups, "cvt" if i == 0 else "unet", cvt) for i, n in enumerate(cfg.num_hypotheses)]
        )
        if cfg.freeze_vit:
            self.vit.requires_grad_(False)
        self.vit.mask_token.requires_grad_(False)  # in DINOv2 checkpoints, never used here
        self.set_attention_backend(cfg.attention_backend)

    def prepare_for_inference(self) -> MVSFormerPP:
        """Eval mode with the inference forms built (folded BatchNorm, banded U-Nets, in-place work):
        forwards without autograd then run them. ``train()``, ``load_state_dict`` and any change of the
        parameters drop them again (:mod:`mvsformerpp.models.prepared`). Returns the model."""
        return prepared.prepare(self)

    def train(self, mode: bool = True) -> MVSFormerPP:
        if mode:
            prepared.release(self)
        return super().train(mode)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        prepared.release(self)
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def set_attention_backend(self, backend: str) -> None:
        """Softmax attention kernel for DINOv2 and the CVT: sdpa | flash | eager | auto."""
        for m in self.modules():
            if hasattr(m, "backend"):
                m.backend = backend

    def set_attention_precision(self, precision: str) -> None:
        """The stage-1 cost-volume transformer's softmax attention in ``bf16`` (q, k and v rounded to bf16,
        the result back in fp32) inside an fp32 forward, or in ``fp32`` (the default). Under an autocast
        the attention follows the autocast whatever this says."""
        if precision not in ("fp32", "bf16"):
            raise ValueError(f"attention precision must be 'fp32' or 'bf16', got {precision!r}")
        for m in self.modules():
            if isinstance(m, CVTAttention):
                m.bf16 = precision == "bf16"

    def encode_images(self, imgs: torch.Tensor) -> ImageFeatures:
        """Per-image work for [N, 3, H, W] ImageNet-normalised images (H, W multiples of 32)."""
        with prepared.session(self):
            return encode_images(self.vit, self.encoder, imgs, self.config.vit_rescale)

    def forward(self, imgs: torch.Tensor, proj_matrices: dict, depth_values: torch.Tensor,
                temperatures=None, image_features: ImageFeatures | None = None,
                release_features: bool = False, window_guide: dict | None = None, stages: int | None = None) -> dict:
        """Run the cascade.

        Args:
            imgs: [B, V, 3, H, W] ImageNet-normalised RGB, view 0 = reference; H, W multiples of 32.
            proj_matrices: {"stage1".."stage4": [B, V, 2, 4, 4]}: slot 0 world-to-camera 4x4, slot 1
                [:3,:3] intrinsics at that stage's scale (K/8, K/4, K/2, K).
            depth_values: [B, D]; only the first (dmin) and last (dmax) entries are used.
            temperatures: per-stage inference temperatures (default config.temperatures); ignored in
                training mode, which takes the argmax hypothesis.
            image_features: precomputed :meth:`encode_images` output for the B*V images (batch-major);
                ``imgs`` is then only used for its shape.
            release_features: empty ``image_features`` (see :meth:`ImageFeatures.release`) once the
                views are decoded, so that its maps do not stay in memory for the rest of the cascade;
                for callers that built it for this call only.
            window_guide: training only: {"stage1".."stage3": (depth [B,h,w], jitter [B,h,w])}. Where a
                depth is given (> 0), the next stage's window is centred on it, moved by ``jitter`` (in
                [-1, 1]) times the window's half-width, instead of on the stage's own estimate, so that
                the truth lies inside the finer stages' windows (see
                ``TrainConfig.window_guide``). None: the reference's cascade.
            stages: run only the first ``stages`` cascade stages (training the coarse stages alone); the
                outputs then hold those stages, and "depth" is the last one's, at its resolution.
        Returns:
            {"stage1".."stage4": {"depth" [B,h,w], "photometric_confidence" [B,h,w],
            "prob_volume_pre" [B,D,h,w] logits, "depth_values" [B,D,h,w] hypotheses},
            "depth" [B,H,W] (stage 4), "photometric_confidence" [B,H,W] (mean of the 4 stages)}.
        """
        B, V, _, H, W = imgs.shape
        if H % 32 or W % 32:
            raise ValueError(f"image size {H}x{W} must be a multiple of 32: resize or pad")
        if stages is not None and not 1 <= stages <= len(self.fusions):
            raise ValueError(f"stages must be between 1 and {len(self.fusions)}, got {stages}")
        with prepared.session(self):
            return self._forward(imgs, proj_matrices, depth_values, temperatures, image_features, release_features,
                                 window_guide, stages)

    def _forward(self, imgs, proj_matrices, depth_values, temperatures, image_features, release_features,
                 window_guide=None, stages=None) -> dict:
        B, V, _, H, W = imgs.shape
        cfg = self.config
        own = image_features is None
        if own:
            image_features = self.encode_images(imgs.reshape(B * V, *imgs.shape[2:]))
        run = self.fusions if stages is None else self.fusions[:stages]
        features = decode_views(self.decoder_vit, self.decoder, image_features, B, V, len(run))
        if own:
            del image_features  # the encoder maps are not needed any more: free them before the FMT
        elif release_features:
            image_features.release()
        features = self.FMT_module(features)
        temps = tuple(cfg.temperatures if temperatures is None else temperatures)
        dmin_all, dmax_all = depth_values.min(), depth_values.max()
        outputs: dict = {}
        conf_sum = torch.zeros(B, H, W, dtype=torch.float32, device=imgs.device)
        prev = None
        for s, stage in enumerate(run):
            feat, features[s] = features[s], None  # each stage's features are freed after its cost volume
            h, w = feat.shape[-2:]
            proj = proj_matrices[f"stage{s + 1}"]
            if s == 0:
                hyp = initial_hypotheses(depth_values.float(), cfg.num_hypotheses[0], h, w)
                coords = frustum_coordinates(proj[:, 0, 1, :3, :3], hyp, dmin_all, dmax_all)
            else:
                min_inv = 0.1 / depth_values[:, -1].float()
                centre = prev["depth"].detach()
                if window_guide is not None and f"stage{s}" in window_guide:
                    centre = _guided_centre(centre, prev["depth_values"], *window_guide[f"stage{s}"], min_inv,
                                            cfg.hypothesis_ratio[s])
                hyp = refined_hypotheses(centre, prev["depth_values"], cfg.num_hypotheses[s],
                                         cfg.hypothesis_ratio[s], h, w, min_inverse=min_inv)
                coords = None
            volume = stage.cost_volume(feat, proj, hyp)
            del feat
            prev = stage.predict(volume, hyp, None if self.training else temps[s], coords)
            del volume
            outputs[f"stage{s + 1}"] = prev
            conf = prev["photometric_confidence"]
            if conf.shape[-2:] != (H, W):
                conf = F.interpolate(conf[:, None], (H, W), mode="nearest")[:, 0]
            conf_sum = conf_sum + conf
        outputs["depth"] = prev["depth"]
        outputs["photometric_confidence"] = conf_sum / len(run)
        return outputs


def _guided_centre(estimate: torch.Tensor, prev_hypotheses: torch.Tensor, depth: torch.Tensor, jitter: torch.Tensor,
                   min_inverse: torch.Tensor, ratio: float) -> torch.Tensor:
    """The window centre of a guided training sample: ``depth`` (where > 0) moved by ``jitter`` times the
    window's half-width (``ratio`` plane steps of the previous stage in inverse depth, the step
    :func:`refined_hypotheses` measures), so the truth falls anywhere in the window as it does when the
    previous stage is nearly right, not always near its middle; else ``estimate``."""
    step = plane_step(prev_hypotheses).abs()
    inv = (1.0 / depth.clamp(min=1e-6) + jitter * ratio * step).clamp(min=min_inverse[:, None, None])
    return torch.where(depth > 0, 1.0 / inv, estimate)


def build_model(preset: str = "paper", **overrides) -> MVSFormerPP:
    """The network for a named preset (:data:`~mvsformerpp.models.presets.PRESETS`) with config overrides."""
    return MVSFormerPP(get_config(preset, **overrides))
