"""The capture degradations of bench/degradations.py against what they model, and the quality hook they use."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from degradations import (  # noqa: E402
    PHOTO_CONDITIONS,
    _load,
    flat_mask,
    motion_blur,
    preparer,
    radial_distortion,
)

from mvsformerpp.io.mvsnet import read_cam  # noqa: E402
from mvsformerpp.synth import generate_scene  # noqa: E402


def _dot(h, w, y, x, sigma=1.5):
    v, u = np.mgrid[0:h, 0:w]
    g = np.exp(-((u - x) ** 2 + (v - y) ** 2) / (2 * sigma**2)).astype(np.float32)
    return np.repeat(g[..., None], 3, axis=-1)


def _centroid(img):
    g = img[..., 0]
    v, u = np.mgrid[0 : g.shape[0], 0 : g.shape[1]]
    return (v * g).sum() / g.sum(), (u * g).sum() / g.sum()


def test_radial_distortion_moves_a_point_where_the_lens_model_puts_it():
    h, w = 120, 160
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]])
    img = _dot(h, w, 20.0, 30.0)
    np.testing.assert_allclose(radial_distortion(img, K, 0.0), img, atol=1e-6)
    k1 = 0.08
    xu, yu = (30.0 - K[0, 2]) / K[0, 0], (20.0 - K[1, 2]) / K[1, 1]
    f = 1 + k1 * (xu * xu + yu * yu)  # pinhole point -> where the distorted photo shows it
    y, x = _centroid(radial_distortion(img, K, k1))
    assert abs(x - (xu * f * K[0, 0] + K[0, 2])) < 0.3 and abs(y - (yu * f * K[1, 1] + K[1, 2])) < 0.3
    assert x < 30.0 - 1 and y < 20.0 - 1  # barrel of a positive k1: outwards


def test_motion_blur_spreads_a_point_along_its_angle_and_keeps_brightness():
    img = _dot(41, 41, 20.0, 20.0, sigma=0.6)
    blurred = motion_blur(img, 9, 0.0)  # horizontal
    assert blurred.sum() == pytest.approx(img.sum(), rel=1e-3)
    row, col = blurred[20, :, 0], blurred[:, 20, 0]
    assert (row > 0.05 * row.max()).sum() >= 9 and (col > 0.05 * col.max()).sum() <= 3
    vertical = motion_blur(img, 9, np.pi / 2)
    np.testing.assert_allclose(vertical[..., 0], blurred[..., 0].T, atol=1e-5)
    const = np.full((20, 20, 3), 0.3, np.float32)
    np.testing.assert_allclose(motion_blur(const, 7, 1.0), const, atol=1e-6)


def test_flat_mask_finds_plain_paint_not_texture():
    rng = np.random.default_rng(0)
    img = np.full((40, 60, 3), 0.7, np.float32)
    img[:, 30:] = rng.uniform(0, 1, (40, 30, 3))
    mask = flat_mask(img)
    assert mask[:, :25].all() and not mask[:, 35:].any()


def test_preparer_degrades_photos_and_widens_ranges_but_leaves_the_truth(tmp_path):
    scene = generate_scene(tmp_path / "scene_0", seed=3, num_views=2, height=32, width=48, gt_points=2000)
    before = [read_cam(scene / "cams" / f"{i:08d}_cam.txt") for i in range(2)]
    truth = (scene / "depth_gt" / "00000000.pfm").read_bytes()
    photo = _load(scene / "images" / "00000000.png")
    preparer("range_2x", 0)(scene)
    for i, cam in enumerate(before):
        after = read_cam(scene / "cams" / f"{i:08d}_cam.txt")
        assert after.depth_min == pytest.approx(cam.depth_min / 2, rel=1e-5)
        assert after.depth_max == pytest.approx(cam.depth_max * 2, rel=1e-5)
        np.testing.assert_allclose(after.K, cam.K)
    np.testing.assert_array_equal(_load(scene / "images" / "00000000.png"), photo)
    assert (scene / "flat" / "00000000.npy").is_file()
    preparer("noise", 0)(scene)
    noisy = _load(scene / "images" / "00000000.png")
    assert 0.005 < np.abs(noisy - photo).mean() < 0.05
    assert (scene / "depth_gt" / "00000000.pfm").read_bytes() == truth
    assert set(PHOTO_CONDITIONS) >= {"jpeg", "blur", "noise", "exposure", "distortion"}
