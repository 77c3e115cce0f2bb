"""Self-supervision on calibrated photos without depth: photometric consistency and cross-view agreement.

The depth a stage predicts is judged by what it says about the other photos (as unsupervised MVS does,
e.g. Khot et al. 2019, Dai et al. 2019):

* **Photometric consistency**: each source photo is warped into the reference view through the depth
  (:func:`~mvsformerpp.geometry.warping.homography_warp` with one hypothesis per pixel) and compared with the
  reference: ``alpha (1 - SSIM) / 2 + (1 - alpha) |I_ref - (a I_warp + b)|`` (3x3 SSIM, ``alpha`` 0.85), where
  ``a, b`` per source and channel are the least-squares exposure match over the pixels the source sees
  (photos of one scene differ in exposure and white balance; the fit is held fixed in the gradient). Per
  pixel the smallest error over the sources counts (a pixel occluded in one source is usually seen by
  another), and only pixels that at least one source sees.
* **Cross-view agreement**: two samples of one scene whose references are different photos (a pair,
  ``pair_id``) predict two depth maps of the same surfaces: each is lifted to 3-D, projected into the
  other reference, and the relative difference ``|z - D_other(p)| / z`` is averaged where the point lands
  inside and in front, except where the difference exceeds :data:`OCCLUSION` (an occlusion, not an error).

Training (``TrainConfig.self_supervised``) takes the expected depth ``sum_k softmax(logits)_k d_k`` of
each stage at that stage's resolution, which is differentiable where the argmax depth of training mode is
not.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from mvsformerpp.geometry.warping import homography_warp, projection_4x4
from mvsformerpp.models.inputs import IMAGENET_MEAN, IMAGENET_STD

ALPHA = 0.85
"""Weight of the SSIM term against the L1 term (Godard et al. 2017)."""
OCCLUSION = 0.1
"""Relative depth difference above which two views' depths are taken to see different surfaces."""


def unnormalize(imgs: torch.Tensor) -> torch.Tensor:
    """ImageNet-normalised RGB ``[..., 3, H, W]`` -> RGB in [0, 1]."""
    mean = imgs.new_tensor(IMAGENET_MEAN).view(3, 1, 1)
    std = imgs.new_tensor(IMAGENET_STD).view(3, 1, 1)
    return imgs * std + mean


def soft_depth(logits: torch.Tensor, hypotheses: torch.Tensor) -> torch.Tensor:
    """Expected depth ``sum_k softmax(logits)_k d_k`` [B, H, W] of [B, D, H, W] logits and hypotheses."""
    return (F.softmax(logits.float(), dim=1) * hypotheses.float()).sum(dim=1)


def ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM [B, C, H, W] over 3x3 windows (reflection-padded)."""
    c1, c2 = 0.01**2, 0.03**2
    pool = lambda t: F.avg_pool2d(F.pad(t, (1, 1, 1, 1), mode="reflect"), 3, 1)  # noqa: E731
    mx, my = pool(x), pool(y)
    sx, sy, sxy = pool(x * x) - mx * mx, pool(y * y) - my * my, pool(x * y) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sx + sy + c2))


def exposure_match(warped: torch.Tensor, ref: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``a * warped + b`` per image and channel, ``a, b`` the least-squares fit to ``ref`` over ``valid`` pixels
    (held fixed: no gradient through the fit). ``warped``, ``ref`` [B, C, H, W], ``valid`` [B, H, W]."""
    with torch.no_grad():
        w = valid[:, None].float()
        n = w.sum((2, 3)).clamp(min=1.0)
        mx, my = (warped * w).sum((2, 3)) / n, (ref * w).sum((2, 3)) / n
        cov = ((warped - mx[..., None, None]) * (ref - my[..., None, None]) * w).sum((2, 3)) / n
        var = ((warped - mx[..., None, None]) ** 2 * w).sum((2, 3)) / n
        a = (cov / var.clamp(min=1e-6)).clamp(0.5, 2.0)
        b = my - a * mx
    return a[..., None, None] * warped + b[..., None, None]


def photometric_error(imgs: torch.Tensor, K: torch.Tensor, E: torch.Tensor, depth: torch.Tensor):
    """Per-pixel photometric error of a reference depth map and the pixels some source sees.

    Args:
        imgs: [B, V, 3, H, W] RGB in [0, 1], view 0 the reference (at the depth map's resolution).
        K: [B, V, 3, 3] intrinsics at that resolution; E: [B, V, 4, 4] world-to-camera.
        depth: [B, H, W] reference z-depth.
    Returns:
        (error [B, H, W]: the smallest error over the sources, valid [B, H, W]: seen by at least one).
    """
    B, V, _, H, W = imgs.shape
    ref = imgs[:, 0]
    ref_proj = projection_4x4(E[:, 0], K[:, 0])
    errors, seen = [], []
    for v in range(1, V):
        src = torch.cat([imgs[:, v], torch.ones_like(imgs[:, v, :1])], dim=1)
        warped = homography_warp(src, projection_4x4(E[:, v], K[:, v]), ref_proj, depth[:, None])[:, :, 0]
        inside = (warped[:, 3] > 0.999) & (depth > 0)
        rgb = exposure_match(warped[:, :3], ref, inside)
        err = ALPHA * (1 - ssim(rgb, ref)).clamp(0, 2).mean(1) / 2 + (1 - ALPHA) * (rgb - ref).abs().mean(1)
        errors.append(torch.where(inside, err, torch.full_like(err, 1e3)))
        seen.append(inside)
    error = torch.stack(errors).min(dim=0).values
    valid = torch.stack(seen).any(dim=0)
    return torch.where(valid, error, torch.zeros_like(error)), valid


def cross_view_error(depth_a: torch.Tensor, K_a: torch.Tensor, E_a: torch.Tensor, depth_b: torch.Tensor,
                     K_b: torch.Tensor, E_b: torch.Tensor):
    """Relative disagreement of view a's depth with view b's: (error [B, H, W], valid [B, H, W]).

    Each pixel of a, lifted to 3-D at ``depth_a`` and projected into b, should land on b's depth there;
    ``|z_b - depth_b(p)| / z_b``, valid where the point is in front of b, inside its image and the
    difference is below :data:`OCCLUSION`. Depths [B, H, W], K [B, 3, 3], E [B, 4, 4].
    """
    B, H, W = depth_a.shape
    y, x = torch.meshgrid(torch.arange(H, device=depth_a.device, dtype=torch.float32),
                          torch.arange(W, device=depth_a.device, dtype=torch.float32), indexing="ij")
    pix = torch.stack([x, y, torch.ones_like(x)]).reshape(1, 3, -1)
    rays = torch.linalg.inv(K_a.float()) @ pix  # [B, 3, HW]
    cam_a = rays * depth_a.reshape(B, 1, -1)
    rel = E_b.float() @ torch.linalg.inv(E_a.float())  # a's camera frame -> b's
    cam_b = rel[:, :3, :3] @ cam_a + rel[:, :3, 3:]
    z = cam_b[:, 2]
    uv = (K_b.float() @ cam_b)[:, :2] / z.clamp(min=1e-6)[:, None]
    grid = torch.stack([uv[:, 0] / ((W - 1) / 2) - 1, uv[:, 1] / ((H - 1) / 2) - 1], dim=-1).reshape(B, H, W, 2)
    sampled = F.grid_sample(depth_b[:, None].float(), grid, mode="bilinear", padding_mode="zeros",
                            align_corners=True)[:, 0]
    z = z.reshape(B, H, W)
    inside = (z > 1e-6) & (grid.abs() <= 1).all(-1) & (sampled > 0) & (depth_a > 0)
    err = (z - sampled).abs() / z.clamp(min=1e-6)
    valid = inside & (err.detach() < OCCLUSION)
    return torch.where(valid, err, torch.zeros_like(err)), valid


def _mean(err: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    return (err * valid).sum() / valid.sum().clamp(min=1)


def self_supervised_loss(outputs: dict, batch: dict, stages=("stage1", "stage2", "stage3", "stage4"),
                         agreement_weight: float = 1.0) -> tuple[torch.Tensor, dict]:
    """Photometric consistency of every stage's expected depth plus cross-view agreement of the last stage, over
    the samples with ``batch["self_supervised"] > 0``; returns (loss, {"photometric": .., "agreement": ..}), the
    terms empty when the batch has no such sample.

    ``batch``: the training batch (``imgs`` normalised [B, V, 3, H, W], ``proj_matrices`` {stage: [B, V, 2, 4,
    4]}, ``self_supervised`` [B], ``pair_id`` [B]: samples with the same id >= 0 are two references of one
    scene). A batch without such samples gives a zero loss with a gradient path.
    """
    picked = batch["self_supervised"] > 0
    zero = sum(outputs[s]["prob_volume_pre"].sum() for s in stages if s in outputs) * 0.0
    if not picked.any():
        return zero, {}
    imgs = unnormalize(batch["imgs"][picked].float())
    photo = []
    depths = {}
    for s in stages:
        if s not in outputs:
            continue
        o = outputs[s]
        depth = soft_depth(o["prob_volume_pre"][picked], o["depth_values"][picked])
        h, w = depth.shape[-2:]
        P = batch["proj_matrices"][s][picked]
        small = F.interpolate(imgs.flatten(0, 1), size=(h, w), mode="area").unflatten(0, imgs.shape[:2])
        err, valid = photometric_error(small, P[:, :, 1, :3, :3], P[:, :, 0], depth)
        photo.append(_mean(err, valid))
        depths[s] = (depth, P)
    loss_photo = torch.stack(photo).mean()
    agree = []
    last = [s for s in stages if s in depths][-1]
    depth, P = depths[last]
    pair = batch["pair_id"][picked]
    for i in range(len(pair)):
        for j in range(len(pair)):
            if i != j and pair[i] >= 0 and pair[i] == pair[j]:
                err, valid = cross_view_error(depth[i:i + 1], P[i:i + 1, 0, 1, :3, :3], P[i:i + 1, 0, 0],
                                              depth[j:j + 1], P[j:j + 1, 0, 1, :3, :3], P[j:j + 1, 0, 0])
                agree.append(_mean(err, valid))
    loss_agree = torch.stack(agree).mean() if agree else loss_photo * 0.0
    total = zero + loss_photo + agreement_weight * loss_agree
    return total, {"photometric": float(loss_photo.detach()), "agreement": float(loss_agree.detach())}
