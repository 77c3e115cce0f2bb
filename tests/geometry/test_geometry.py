"""Geometry with exact evidence: warping at the true depth reproduces the reference view."""

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mvsformerpp.geometry.camera import (
    backproject,
    crop_intrinsics,
    depth_to_points,
    pad_intrinsics,
    pixel_grid,
    project,
    scale_intrinsics,
)
from mvsformerpp.geometry.warping import homography_warp, projection_4x4
from mvsformerpp.io.mvsnet import read_cam
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.synth import random_scene, render_view

DTU = Path(__file__).parents[1] / "data" / "dtu_pair"


def _t(a):
    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


def test_project_backproject_round_trip():
    rng = np.random.default_rng(0)
    K = _t([[500, 0, 320], [0, 510, 240], [0, 0, 1]])
    E = torch.eye(4, dtype=torch.float64)
    E[:3, 3] = _t([0.1, -0.2, 0.3])
    u, v, d = _t(rng.uniform(0, 640, 50)), _t(rng.uniform(0, 480, 50)), _t(rng.uniform(1, 5, 50))
    pts = backproject(K, E, u, v, d)
    u2, v2, d2 = project(K, E, pts)
    torch.testing.assert_close((u2, v2, d2), (u, v, d))
    uu, vv = pixel_grid(2, 3)
    assert uu.tolist() == [0.5, 1.5, 2.5] * 2 and vv.tolist() == [0.5] * 3 + [1.5] * 3


def test_intrinsics_under_resize_crop_pad_match_rendering():
    """Rendering at half resolution with scale_intrinsics(K, 0.5) is exact: on a plane inverse depth is
    affine in the image, so each half-resolution pixel equals the mean of its 2x2 full-resolution block."""
    scene = random_scene(1, 1, 64, 80)
    cam = scene.cameras[0]
    full = 1 / render_view(scene, cam)[1].astype(np.float64)
    cam.K = scale_intrinsics(cam.K, 0.5)
    scene.height, scene.width = 32, 40
    half = 1 / render_view(scene, cam)[1].astype(np.float64)
    blocks = full.reshape(32, 2, 40, 2)
    planar = np.abs(blocks[:, 0, :, 0] + blocks[:, 1, :, 1] - blocks[:, 0, :, 1] - blocks[:, 1, :, 0]) < 1e-7
    assert planar.mean() > 0.5
    rel = np.abs(half[planar] / blocks.mean(axis=(1, 3))[planar] - 1)
    assert np.mean(rel < 2e-6) > 0.995  # (a block straddling an occlusion edge can look planar by chance)
    K = np.array([[100.0, 0, 40], [0, 100, 30], [0, 0, 1]])
    np.testing.assert_allclose(pad_intrinsics(crop_intrinsics(K, 5, 7), 5, 7), K)
    assert crop_intrinsics(K, 5, 7)[0, 2] == 35 and pad_intrinsics(K, 2, 3)[1, 2] == 33


def _to_tensor(img):
    return torch.tensor(np.asarray(img), dtype=torch.float32).permute(2, 0, 1)[None] / 255


def test_warping_a_synthetic_view_at_true_depth_reproduces_the_reference():
    scene = random_scene(2, 2, 96, 128)
    (ref_img, ref_depth, _), (src_img, _, _) = (render_view(scene, c) for c in scene.cameras)
    # homography_warp uses integer pixel coordinates; the renderer pixel centres (x + 0.5):
    # shifting the principal point by -0.5 makes integer coordinates land on the centres.
    def proj(cam):
        E = torch.eye(4)
        E[:3, :3], E[:3, 3] = torch.tensor(cam.R), torch.tensor(cam.t)
        return projection_4x4(E[None].float(), torch.tensor(crop_intrinsics(cam.K, 0.5, 0.5))[None].float())

    def error(depth):
        warped = homography_warp(_to_tensor(src_img), proj(scene.cameras[1]), proj(scene.cameras[0]),
                                 torch.as_tensor(depth)[None, None].float())[:, :, 0]
        diff = (warped - _to_tensor(ref_img)).abs().mean(1)[0]
        return diff, warped[0].abs().sum(0) > 0

    diff, inside = error(ref_depth)
    wrong, _ = error(ref_depth * 1.05)
    assert inside.float().mean() > 0.7
    assert diff[inside].median() < 0.02  # the same surface point: the same colour (up to sampling)
    assert wrong[inside].median() > 3 * diff[inside].median()


def test_real_dtu_pair_warps_best_at_true_depth():
    cams = [read_cam(DTU / f"0000000{i}_cam.txt") for i in (0, 1)]
    imgs = [np.asarray(Image.open(DTU / f"rect_00{i + 1}_0_r5000.png").convert("RGB").resize((160, 128), Image.BOX))
            for i in (0, 1)]
    depth = read_pfm(DTU / "depth_map_0000.pfm")
    valid = torch.as_tensor(depth > 0)
    projs = [projection_4x4(torch.tensor(c.extrinsic)[None].float(), torch.tensor(c.K)[None].float()) for c in cams]

    def photometric_error(scale):
        d = torch.as_tensor(depth * scale)[None, None].float()
        warped = homography_warp(_to_tensor(imgs[1]), projs[1], projs[0], d)[:, :, 0]
        m = valid & (warped[0].abs().sum(0) > 0)
        return float((warped - _to_tensor(imgs[0])).abs().mean(1)[0][m].mean())

    true = photometric_error(1.0)
    for wrong in (0.95, 1.05):
        assert photometric_error(wrong) > 1.3 * true, (true, photometric_error(wrong))


def test_dtu_pair_depth_pixel_j_lies_on_photo_pixel_4j():
    """The 160x128 ground truth belongs to the 640x512 photos with K scaled by 4 in integer pixel coordinates:
    depth pixel j on photo pixel 4j (where the quality check compares it), not at its 4x4 block's centre."""
    cams = [read_cam(DTU / f"0000000{i}_cam.txt") for i in (0, 1)]
    imgs = [_to_tensor(np.asarray(Image.open(DTU / f"rect_00{i + 1}_0_r5000.png").convert("RGB"))) for i in (0, 1)]

    def proj(c):
        K = c.K.copy()
        K[:2] *= 4
        return projection_4x4(torch.tensor(c.extrinsic)[None].float(), torch.tensor(K)[None].float())

    depth = read_pfm(DTU / "depth_map_0000.pfm")
    h, w = depth.shape
    ys, xs = np.mgrid[0 : 4 * h, 0 : 4 * w]

    def photometric_error(offset):  # depth pixel j placed at photo coordinate 4j + offset
        d = depth[np.clip(np.round((ys - offset) / 4).astype(int), 0, h - 1),
                  np.clip(np.round((xs - offset) / 4).astype(int), 0, w - 1)]
        warped = homography_warp(imgs[1], proj(cams[1]), proj(cams[0]), torch.from_numpy(d)[None, None].float())
        m = torch.from_numpy(d > 0) & (warped[0, :, 0].abs().sum(0) > 0)
        return float((warped[:, :, 0] - imgs[0]).abs().mean(1)[0][m].mean())

    at_4j, block_centre = photometric_error(0.0), photometric_error(1.5)
    assert block_centre > 1.03 * at_4j  # measured: 4.5 % more error 1.5 px away
    assert photometric_error(0.5) > at_4j and photometric_error(-0.5) >= 0.99 * at_4j


def test_depth_to_points_matches_backproject():
    K = _t([[50, 0, 8], [0, 50, 6], [0, 0, 1]])
    E = torch.eye(4, dtype=torch.float64)
    depth = torch.full((3, 4), 2.0, dtype=torch.float64)
    pts = depth_to_points(depth, K, E)
    assert pts.shape == (3, 4, 3)
    torch.testing.assert_close(pts[0, 0], _t([(0.5 - 8) / 50 * 2, (0.5 - 6) / 50 * 2, 2.0]))


@pytest.mark.parametrize("s", [0.5, 2.0])
def test_scale_intrinsics_maps_projections(s):
    K = np.array([[100.0, 0, 40], [0, 120, 30], [0, 0, 1]])
    X = np.array([0.3, -0.2, 2.0])
    p, q = K @ X, scale_intrinsics(K, s) @ X
    np.testing.assert_allclose(q[:2] / q[2], s * p[:2] / p[2])


def test_warp_is_the_same_with_and_without_autograd_and_in_hypothesis_chunks():
    """The in-place sampling grid (no autograd) repeats the differentiable form's operations exactly,
    and chunks of hypotheses with precomputed per-view rays give the same warp as one call."""
    from mvsformerpp.geometry.warping import warp_rays

    torch.manual_seed(0)
    K = torch.tensor([[60.0, 0, 40], [0, 60, 30], [0, 0, 1]])
    E_ref, E_src = torch.eye(4), torch.eye(4)
    c, s = np.cos(0.1), np.sin(0.1)
    E_src[:3, :3] = torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=torch.float32)
    E_src[0, 3] = 3.0
    ref_proj, src_proj = projection_4x4(E_ref[None], K[None]), projection_4x4(E_src[None], K[None])
    feat = torch.randn(1, 4, 60, 80)
    depth = (torch.rand(1, 6, 60, 80) * 20 + 30).requires_grad_()
    with_grad = homography_warp(feat, src_proj, ref_proj, depth)
    plain = homography_warp(feat, src_proj, ref_proj, depth.detach())
    rays = warp_rays(src_proj, ref_proj, 60, 80)
    chunks = torch.cat([homography_warp(feat, src_proj, ref_proj, depth.detach()[:, d:d + 2], rays)
                        for d in range(0, 6, 2)], 2)
    assert torch.equal(with_grad.detach(), plain) and torch.equal(plain, chunks)


def test_warp_in_blocks_of_hypotheses_gives_the_same_values():
    """blocks > 1 samples one image's hypotheses as a batch of blocks (so that PyTorch's CPU grid_sample,
    parallel over the batch only, uses every thread): block k holds hypotheses k*D/blocks onwards with the
    values of one call, bit for bit; it refuses batches, autograd and a hypothesis count it cannot split."""
    torch.manual_seed(1)
    K = torch.tensor([[60.0, 0, 40], [0, 60, 30], [0, 0, 1]])
    E_src = torch.eye(4)
    E_src[0, 3] = 2.5
    ref_proj, src_proj = projection_4x4(torch.eye(4)[None], K[None]), projection_4x4(E_src[None], K[None])
    feat = torch.randn(1, 6, 60, 80).contiguous(memory_format=torch.channels_last)  # as the network's features
    depth = torch.rand(1, 8, 60, 80) * 20 + 30
    whole = homography_warp(feat, src_proj, ref_proj, depth)
    for blocks in (2, 4, 8):
        parts = homography_warp(feat, src_proj, ref_proj, depth, blocks=blocks)
        assert parts.shape == (blocks, 6, 8 // blocks, 60, 80)
        assert torch.equal(torch.cat(list(parts), 1)[None], whole)
    with pytest.raises(ValueError, match="multiple of 3"):
        homography_warp(feat, src_proj, ref_proj, depth, blocks=3)
    with pytest.raises(ValueError, match="one image"):
        homography_warp(feat.expand(2, -1, -1, -1), src_proj.expand(2, -1, -1), ref_proj.expand(2, -1, -1),
                        depth.expand(2, -1, -1, -1), blocks=2)
    with pytest.raises(ValueError, match="without autograd"):
        homography_warp(feat, src_proj, ref_proj, depth.requires_grad_(), blocks=2)


def test_the_lean_cost_volume_is_the_same_on_any_number_of_threads():
    """The inference cost volume warps in blocks of hypotheses, one per thread: the volume is the same
    on 1-4 threads (up to the rounding of the visibility net's threaded convolutions) and equals the one
    built with autograd on (no blocks, no in-place buffers)."""
    from mvsformerpp.models import prepared
    from mvsformerpp.models.cost_volume import StageNet

    torch.manual_seed(2)
    stage = StageNet(8, groups=4).eval()
    K = torch.tensor([[50.0, 0, 32], [0, 50, 24], [0, 0, 1]])
    proj = torch.zeros(1, 3, 2, 4, 4)
    proj[:, :, 0] = torch.eye(4)
    proj[0, 1, 0, 0, 3], proj[0, 2, 0, 1, 3] = 1.5, -1.0
    proj[:, :, 1, :3, :3], proj[:, :, 1, 3, 3] = K, 1.0
    feats = torch.randn(1, 3, 8, 48, 64)
    hyp = torch.linspace(20.0, 40.0, 8).view(1, 8, 1, 1).expand(1, 8, 48, 64).contiguous()
    with torch.enable_grad():
        reference = stage.cost_volume(feats, proj, hyp.requires_grad_()).detach()
    threads = torch.get_num_threads()
    volumes = []
    try:
        for n in (1, 2, 3, 4):
            torch.set_num_threads(n)
            with torch.no_grad(), prepared.session(stage):
                assert prepared.lean()
                volumes.append(stage.cost_volume(feats, proj, hyp.detach()))
    finally:
        torch.set_num_threads(threads)
    for v in volumes:
        torch.testing.assert_close(v, reference, rtol=1e-5, atol=1e-6)
