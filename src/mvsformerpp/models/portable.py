"""The network as two portable graphs (the forms ``export-onnx`` writes as ONNX).

The split is the one inference already makes (:mod:`.features`): the per-image part runs once per image
and its outputs are cached, the per-view-set part runs once per reference view on the cached features of
its images.

* :class:`EncoderGraph`: ImageNet-normalised images -> the three DINOv2 (or lite ViT) taps on their token
  grid and the FPN encoder's four maps;
* :class:`ViewSetGraph`: the features of one view set (reference first), the cameras prepared outside
  (:func:`~mvsformerpp.geometry.warping.relative_projections`: the graph holds no matrix inverse) and the
  depth range -> depth and confidence (and, optionally, every stage's outputs).

Both are built from the network's plain modules (eval BatchNorm, 3-D convolutions: not the CPU inference
forms of :mod:`.prepared`) with three replacements that keep the numbers: the bicubic resizes in gathers
(:mod:`.bicubic`), the cameras as inputs, and softmax attention in plain matrix products (the stage-1
transformer over query chunks). Image sizes are symbolic: any multiple of 32; the view count is fixed.
"""

from __future__ import annotations

import contextlib
import math

import torch
import torch.nn.functional as F
from torch import nn

from mvsformerpp.geometry.warping import pixel_rays, sampling_grid
from mvsformerpp.models.bicubic import bicubic_resize, inverse_factor
from mvsformerpp.models.cost_volume import group_correlation, matching_entropy, visibility
from mvsformerpp.models.cvt import CVTAttention, frustum_coordinates_from_inverse
from mvsformerpp.models.dinov2 import DinoVisionTransformer
from mvsformerpp.models.features import ImageFeatures, decode_views
from mvsformerpp.models.hypotheses import initial_hypotheses, refined_hypotheses
from mvsformerpp.models.inputs import STAGE_SCALES

ENCODER_INPUTS = ("images",)
ENCODER_OUTPUTS = ("vit_tap0", "vit_tap1", "vit_tap2", "fpn_full", "fpn_half", "fpn_quarter", "fpn_eighth")
CAMERA_INPUTS = ("source_from_reference", "reference_intrinsics_inverse", "depth_range")
VIEW_SET_INPUTS = ENCODER_OUTPUTS + CAMERA_INPUTS
VIEW_SET_OUTPUTS = ("depth", "confidence")
STAGE_OUTPUTS = ("depth", "confidence", "logits", "hypotheses")
"""Per-stage outputs (``stage{1..4}_{name}``) of a view-set graph exported with them."""


def stage_output_names(stages: int = 4) -> tuple[str, ...]:
    return tuple(f"stage{s}_{name}" for s in range(1, stages + 1) for name in STAGE_OUTPUTS)


def portable_pos_embed(vit: DinoVisionTransformer, h, w) -> torch.Tensor:
    """:meth:`DinoVisionTransformer.interpolate_pos_embed` for a symbolic token grid h x w: the same bicubic
    resampling of the square grid with DINOv2's ``scale_factor=(h + 0.1) / grid`` form, and the stored
    embedding itself where h = w = grid (there the resampling's scale becomes 1, which reads every sample
    at its own position: weights 0, 1, 0, 0)."""
    n = vit.pos_embed.shape[1] - 1
    grid = math.isqrt(n)
    pos = vit.pos_embed.float()
    patch = pos[:, 1:].reshape(1, grid, grid, -1).permute(0, 3, 1, 2)
    hs, ws = torch.scalar_tensor(h, dtype=torch.float64), torch.scalar_tensor(w, dtype=torch.float64)
    same = (hs == grid) & (ws == grid)
    one = torch.ones((), dtype=torch.float32)
    scale = tuple(torch.where(same, one, inverse_factor((s + 0.1) / grid)) for s in (hs, ws))
    patch = bicubic_resize(patch, (h, w), scale).permute(0, 2, 3, 1).reshape(1, h * w, -1)
    return torch.cat((pos[:, :1], patch), dim=1)


class EncoderGraph(nn.Module):
    """images [N, 3, H, W] (ImageNet-normalised RGB, H and W multiples of 32) -> the per-image features:
    ``vit_tap0..2`` [N, C_vit, H/32, W/32] (the ViT's taps on its token grid, channels first) and
    ``fpn_full`` [N, c0, H, W], ``fpn_half`` [N, c1, H/2, W/2], ``fpn_quarter`` [N, c2, H/4, W/4],
    ``fpn_eighth`` [N, c3, H/8, W/8] (the FPN encoder)."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.vit, self.encoder = model.vit, model.encoder

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, ...]:
        N, _, H, W = images.shape
        h, w = H // 32, W // 32  # the ViT input is H * 7/16 (a 14-pixel patch per 32 pixels): an h x w grid
        patch = self.vit.patch_size
        vit_in = bicubic_resize(images, (patch * h, patch * w))
        taps = self.vit.forward_taps(vit_in, portable_pos_embed(self.vit, h, w))
        grids = tuple(t.transpose(1, 2).reshape(N, -1, h, w) for t in taps)
        return (*grids, *self.encoder(images))


class ViewSetGraph(nn.Module):
    """One view set's features and cameras -> depth [H, W] (scene units) and confidence [H, W] in [0, 1].

    Inputs: :class:`EncoderGraph`'s seven outputs for the ``views`` images (reference first);
    ``source_from_reference`` [views - 1, 3, 4] and ``reference_intrinsics_inverse`` [3, 3] at the images'
    resolution (:func:`~mvsformerpp.geometry.warping.relative_projections`); ``depth_range`` [2]: near, far.
    ``temperatures``: the depth readout's, one per stage (baked into the graph). ``stage_outputs``: also
    return every stage's depth, confidence, logits and hypotheses (:func:`stage_output_names`).
    """

    def __init__(self, model: nn.Module, views: int, temperatures, stage_outputs: bool = False):
        super().__init__()
        self.decoder_vit, self.decoder, self.fmt, self.fusions = (model.decoder_vit, model.decoder, model.FMT_module,
                                                                   model.fusions)
        cfg = model.config
        self.views, self.stage_outputs = int(views), bool(stage_outputs)
        self.temperatures = tuple(float(t) for t in temperatures)
        self.num_hypotheses, self.ratios = tuple(cfg.num_hypotheses), tuple(cfg.hypothesis_ratio)

    def forward(self, vit_tap0, vit_tap1, vit_tap2, fpn_full, fpn_half, fpn_quarter, fpn_eighth, source_from_reference,
                reference_intrinsics_inverse, depth_range) -> tuple[torch.Tensor, ...]:
        V, H, W = self.views, fpn_full.shape[-2], fpn_full.shape[-1]
        taps = [t.flatten(2).transpose(1, 2) for t in (vit_tap0, vit_tap1, vit_tap2)]
        feats = ImageFeatures(taps, (vit_tap0.shape[-2], vit_tap0.shape[-1]),
                              (fpn_full, fpn_half, fpn_quarter, fpn_eighth))
        features = self.fmt(decode_views(self.decoder_vit, self.decoder, feats, 1, V, len(self.fusions)))
        depth_values = depth_range.reshape(1, 2)
        dmin, dmax = depth_range.min(), depth_range.max()
        conf_sum = torch.zeros(1, H, W, dtype=torch.float32)
        extra, prev = [], None
        for s, stage in enumerate(self.fusions):
            feat = features[s]
            f = STAGE_SCALES[f"stage{s + 1}"]
            h, w = feat.shape[-2:]
            if s == 0:
                hyp = initial_hypotheses(depth_values, self.num_hypotheses[0], h, w)
                k_inv = reference_intrinsics_inverse * torch.tensor([1 / f, 1 / f, 1.0])  # inv(diag(f, f, 1) K)
                coords = frustum_coordinates_from_inverse(k_inv[None], hyp, dmin, dmax)
            else:
                hyp = refined_hypotheses(prev["depth"], prev["depth_values"], self.num_hypotheses[s], self.ratios[s],
                                         h, w, min_inverse=0.1 / depth_values[:, -1])
                coords = None
            # the relative projection at this stage's scale: diag(f, f, 1) [R | t] diag(1/f, 1/f, 1, 1), exact
            rel = source_from_reference * torch.tensor([f, f, 1.0])[:, None] * torch.tensor([1 / f, 1 / f, 1, 1])
            volume = portable_cost_volume(stage, feat, rel, hyp)
            prev = stage.predict(volume, hyp, self.temperatures[s], coords)
            conf = prev["photometric_confidence"]
            if s < len(self.fusions) - 1:
                conf = F.interpolate(conf[:, None], (H, W), mode="nearest")[:, 0]
            conf_sum = conf_sum + conf
            extra += [prev["depth"][0], prev["photometric_confidence"][0], prev["prob_volume_pre"][0], hyp[0]]
        out = (prev["depth"][0], (conf_sum / len(self.fusions))[0])
        return out + tuple(extra) if self.stage_outputs else out


def portable_cost_volume(stage: nn.Module, features: torch.Tensor, relative: torch.Tensor,
                         hypotheses: torch.Tensor) -> torch.Tensor:
    """:meth:`~mvsformerpp.models.cost_volume.StageNet.cost_volume` from relative projections: features
    [1, V, C, h, w], ``relative`` [V-1, 3, 4] at this scale, hypotheses [1, D, h, w] -> [1, G, D, h, w].
    Every hypothesis and every source view at once (the views as a batch: one warp, one visibility net, a
    sum over the batch), so that the graph does not grow with the view count."""
    ref, src = features[:, 0], features[0, 1:]
    S, C, h, w = src.shape
    D = hypotheses.shape[1]
    rot_xyz, trans = pixel_rays(relative, h, w)
    grid = sampling_grid(rot_xyz, trans, hypotheses.reshape(1, 1, D, h * w).expand(S, -1, -1, -1), h, w)
    warped = F.grid_sample(src, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    corr = group_correlation(ref.expand(S, -1, -1, -1), warped.reshape(S, C, D, h, w), stage.groups)
    weight = visibility(stage.vis, matching_entropy(corr))  # [S, 1, h, w]
    volume = (corr * weight[:, None]).sum(0, keepdim=True)
    return volume / (weight.sum(0, keepdim=True)[:, None] + 1e-6)


@contextlib.contextmanager
def portable_attention(model: nn.Module):
    """Softmax attention in plain matrix products while the block runs (exporting ``model``'s graphs): the
    ViT's ``eager``, the stage-1 transformer's ``chunked`` (:mod:`.attention`); the backends before are put
    back afterwards."""
    saved = [(m, m.backend) for m in model.modules() if hasattr(m, "backend")]
    try:
        for m, _ in saved:
            m.backend = "chunked" if isinstance(m, CVTAttention) else "eager"
        yield model
    finally:
        for m, backend in saved:
            m.backend = backend
