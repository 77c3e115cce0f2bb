"""Self-supervision on a rendered scene with exact depth: the true depth scores a lower loss than wrong ones,
the loss's gradient points back to the truth, exposure changes between photos cost nothing."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mvsformerpp.models.inputs import normalize, stage_projections
from mvsformerpp.synth import random_scene, render_view
from mvsformerpp.training.self_supervision import (
    cross_view_error,
    photometric_error,
    self_supervised_loss,
    soft_depth,
)

H, W = 64, 80


@pytest.fixture(scope="module")
def views():
    """(images [1, V, 3, H, W] in [0, 1], K [1, V, 3, 3], E [1, V, 4, 4], depths [V, H, W]) of a textured scene.

    The renderer's pixel (x, y) looks through its centre (x + 0.5, y + 0.5); the warp uses integer pixel
    coordinates, so K's principal point moves by half a pixel."""
    scene = random_scene(5, num_views=3, height=H, width=W, arc_degrees=20.0)
    imgs, Ks, Es, depths = [], [], [], []
    for cam in scene.cameras:
        image, depth, _ = render_view(scene, cam)
        K = cam.K.copy()
        K[:2, 2] -= 0.5
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = cam.R, cam.t
        imgs.append(image)
        Ks.append(K)
        Es.append(E)
        depths.append(depth)
    imgs = torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2).float()[None] / 255
    return imgs, torch.tensor(np.stack(Ks))[None].float(), torch.tensor(np.stack(Es))[None].float(), \
        torch.from_numpy(np.stack(depths))


def _photo_loss(imgs, K, E, depth):
    err, valid = photometric_error(imgs, K, E, depth[None])
    return (err * valid).sum() / valid.sum()


def test_true_depth_scores_lower_than_wrong_depths(views):
    imgs, K, E, depths = views
    true = depths[0]
    assert (true > 0).all()
    loss = _photo_loss(imgs, K, E, true)
    for wrong in (true * 1.04, true * 0.95, true + torch.randn(H, W).abs() * 0.1 * true.mean()):
        assert loss < 0.8 * _photo_loss(imgs, K, E, wrong)


def test_the_gradient_points_to_the_true_depth(views):
    imgs, K, E, depths = views
    for start, sign in ((1.05, 1), (0.95, -1)):
        s = torch.tensor(start, requires_grad=True)
        _photo_loss(imgs, K, E, depths[0] * s).backward()
        assert s.grad * sign > 0  # descending moves the scale back towards 1


def test_exposure_differences_cost_nothing(views):
    imgs, K, E, depths = views
    darker = imgs.clone()
    darker[:, 1:] = darker[:, 1:] * torch.tensor([0.7, 0.8, 0.75]).view(1, 3, 1, 1)  # other gain, white balance
    base = _photo_loss(imgs, K, E, depths[0])
    assert _photo_loss(darker, K, E, depths[0]) < base * 1.3 + 0.01
    assert _photo_loss(darker, K, E, depths[0]) < 0.8 * _photo_loss(darker, K, E, depths[0] * 1.04)


def test_cross_view_agreement(views):
    _, K, E, depths = views
    err, valid = cross_view_error(depths[0][None], K[:, 0], E[:, 0], depths[1][None], K[:, 1], E[:, 1])
    assert valid.float().mean() > 0.5 and (err * valid).sum() / valid.sum() < 0.003
    err2, valid2 = cross_view_error(depths[0][None] * 1.05, K[:, 0], E[:, 0], depths[1][None], K[:, 1], E[:, 1])
    assert (err2 * valid2).sum() / valid2.sum() > 0.02


def test_loss_from_logits_prefers_the_truth_and_reaches_every_stage(views):
    """Fake network outputs whose logits peak at the true depth (or at 5 % too far): the loss through the
    expected depth is lower for the truth, finite, and has a gradient for every stage's logits."""
    imgs, K, E, depths = views
    projs = stage_projections(E[0].double().numpy(), K[0].double().numpy())
    batch = {"imgs": normalize(imgs), "proj_matrices": projs, "self_supervised": torch.tensor([1.0]),
             "pair_id": torch.tensor([-1])}

    def outputs(scale):
        out = {}
        for s, step in (("stage1", 8), ("stage2", 4), ("stage3", 2), ("stage4", 1)):
            d = depths[0][::step, ::step][None] * scale  # [1, h, w]
            hyp = d[:, None] * torch.linspace(0.9, 1.1, 8).view(1, 8, 1, 1) / scale  # true depth in the middle
            logits = -((hyp - d[:, None]) / (0.02 * d[:, None])) ** 2
            out[s] = {"prob_volume_pre": logits.clone().requires_grad_(True), "depth_values": hyp}
        return out

    good, bad = outputs(1.0), outputs(1.05)
    loss_good, parts = self_supervised_loss(good, batch)
    loss_bad, _ = self_supervised_loss(bad, batch)
    assert torch.isfinite(loss_good) and loss_good < loss_bad and parts["agreement"] == 0.0
    loss_good.backward()
    for s in good:
        assert good[s]["prob_volume_pre"].grad.abs().sum() > 0
    assert torch.allclose(soft_depth(good["stage4"]["prob_volume_pre"], good["stage4"]["depth_values"])[0],
                          depths[0], rtol=2e-3)
    # samples without the flag: zero loss, still a graph
    batch["self_supervised"] = torch.tensor([0.0])
    loss, _ = self_supervised_loss(outputs(1.0), batch)
    assert loss == 0 and loss.requires_grad
