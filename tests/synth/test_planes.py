"""Plane scenes: exact depth, views consistent with it under the network's own warp, the MVSNet layout."""

import numpy as np
import pytest
import torch

from mvsformerpp.synth.planes import plane_scene, write_plane_scene

CASES = [dict(), dict(verge=True), dict(tilt_deg=40.0), dict(tilt_deg=25.0, verge=True),
         dict(tilt_deg=35.0, tilt_axis="y")]


def _warp_residual(scene, j: int, depth: np.ndarray) -> float:
    """Mean |reference - source j warped at ``depth``| where the match is inside source j, with the package's warp.

    The photos put pixel centres at +0.5 and the warp at the integer index, so both K lose half a pixel."""
    from mvsformerpp.geometry.warping import homography_warp, projection_4x4

    K = scene.K.copy()
    K[:2, 2] -= 0.5

    def proj(E):
        return projection_4x4(torch.from_numpy(E).float()[None], torch.from_numpy(K).float()[None])

    def img(a):
        return torch.from_numpy(a).permute(2, 0, 1).float()[None] / 255

    source = img(scene.images[j])
    source = torch.cat([source, torch.ones_like(source[:, :1])], 1)  # a fourth channel: 1 inside the photo
    warped = homography_warp(source, proj(scene.extrinsics[j]), proj(scene.extrinsics[0]),
                             torch.from_numpy(depth).float()[None, None])[0, :, 0]
    inside = warped[3] > 0.999  # reference pixels whose match lies inside source j
    diff = (warped[:3] - img(scene.images[0])[0]).abs().mean(0)
    return float(diff[inside].mean())


@pytest.mark.parametrize("kw", CASES)
def test_views_agree_at_the_true_depth_and_not_off_it(kw):
    scene = plane_scene(96, 128, disparity=12.0, **kw)  # 8 % of the depth moves the image by about a pixel
    for j in (1, 4):
        at_truth = _warp_residual(scene, j, scene.depth)
        for factor in (0.92, 1.08):
            assert _warp_residual(scene, j, scene.depth * factor) > 1.5 * at_truth
        assert at_truth < 0.02  # resampling noise only: the photos span about 0..1


@pytest.mark.parametrize("kw", CASES)
def test_reference_depth_is_the_plane_on_each_pixel_centre(kw):
    scene = plane_scene(48, 64, **kw)
    H, W = scene.depth.shape
    ys, xs = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    rays = np.linalg.inv(scene.K) @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    points = rays * scene.depth.ravel()  # z-depth times the ray with z = 1: camera = world frame
    # three points fix the plane; every other point must lie on it
    a, b, c = points[:, 0], points[:, W - 1], points[:, -1]
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal)
    assert np.abs(normal @ (points - a[:, None])).max() < 1e-4 * scene.depth.max()
    tilt = np.degrees(np.arccos(abs(normal[2])))
    assert tilt == pytest.approx(kw.get("tilt_deg", 0.0), abs=0.01)
    if tilt > 1:  # the depth changes down the image (x axis) or across it (y axis), farther up / to the right
        rows, cols = scene.depth.mean(1), scene.depth.mean(0)
        along = rows[0] - rows[-1] if kw.get("tilt_axis", "x") == "x" else cols[-1] - cols[0]
        across = cols[-1] - cols[0] if kw.get("tilt_axis", "x") == "x" else rows[0] - rows[-1]
        assert along > 0.05 * scene.depth.mean() and abs(across) < 1e-3 * scene.depth.mean()
    lo, hi = scene.depth_range
    assert lo < scene.depth.min() and scene.depth.max() < hi


def test_verging_cameras_look_at_the_plane_centre_and_sliding_ones_do_not_turn():
    verge, slide = plane_scene(32, 48, verge=True), plane_scene(32, 48)
    centre = np.array([0.0, 0.0, 2.0, 1.0])
    for E in verge.extrinsics:
        x = verge.K @ (E @ centre)[:3]
        assert x[:2] / x[2] == pytest.approx([24.0, 16.0], abs=1e-6)  # the principal point
    assert all(np.allclose(E[:3, :3], np.eye(3)) for E in slide.extrinsics)
    # the plane's centre moves by the disparity (width / 32 px) between neighbouring sliding cameras
    x0, x1 = ((slide.K @ (E @ centre)[:3]) for E in slide.extrinsics[:2])
    assert abs(x1[0] / x1[2] - x0[0] / x0[2]) == pytest.approx(48 / 32)


def test_bad_geometry_is_refused():
    with pytest.raises(ValueError, match="tilt_deg"):
        plane_scene(32, 48, tilt_deg=80.0)
    with pytest.raises(ValueError, match="tilt_axis"):
        plane_scene(32, 48, tilt_deg=10.0, tilt_axis="z")
    with pytest.raises(ValueError, match="horizon"):
        plane_scene(32, 48, tilt_deg=70.0, focal=10.0)


def test_written_scene_loads_as_an_mvsnet_folder(tmp_path):
    from mvsformerpp.io.detect import load_scene
    from mvsformerpp.io.pfm import read_pfm

    scene = plane_scene(32, 48, verge=True)
    folder = write_plane_scene(tmp_path / "plane", scene)
    loaded = load_scene(folder)
    assert len(loaded) == 5
    ref = loaded.views[0]
    assert np.allclose(ref.K, scene.K) and ref.depth_min == pytest.approx(scene.depth_range[0])
    assert loaded.views[1].neighbors[0] == 0  # nearest camera first
    assert np.array_equal(read_pfm(folder / "depth_gt" / "00000000.pfm"), scene.depth)
