"""Multi-scale resize/crop keeps images, depths and intrinsics consistent; photometric augmentation."""

import numpy as np
import pytest
import torch

from mvsformerpp.data import PhotometricAugment, ResizeCrop, ViewData
from mvsformerpp.errors import InputError
from mvsformerpp.synth import render_view
from mvsformerpp.synth.render import Camera, SynthScene

from .train_utils import rendered_views


def _views(h=96, w=128, seed=4, n=3):
    """(scene, its views with depth) rendered at h x w."""
    scene, views = rendered_views(seed, n, h, w)
    return scene, [ViewData(image, K, E, depth, depth > 0) for image, depth, K, E in views]


def _render(scene, view_index: int, K: np.ndarray, h: int, w: int):
    """The scene rendered directly by a camera with intrinsics K at h x w (independent evidence)."""
    cam = scene.cameras[view_index]
    sub = SynthScene(scene.surfaces, scene.cameras, w, h)
    return render_view(sub, Camera(K, cam.R, cam.t))[:2]


def test_pure_crop_equals_rendering_with_the_adjusted_intrinsics():
    scene, views = _views()
    out = ResizeCrop(scale_range=(1.0, 1.0), min_scale=1.0)(views, 48, 64, np.random.default_rng(1))
    for i, v in enumerate(out):
        image, depth = _render(scene, i, v.K, 48, 64)
        assert np.array_equal(image, v.image)
        np.testing.assert_allclose(depth, v.depth, rtol=1e-6)


@pytest.mark.parametrize("seed", [4, 6])
def test_resize_crop_matches_rendering_with_the_adjusted_intrinsics(seed):
    """Area-resized and cropped photos agree with a direct rendering far better than with K off by 1 px."""
    scene, views = _views(seed=seed)
    out = ResizeCrop(base_size=(96, 128), scale_range=(1.0, 1.2))(views, 48, 64, np.random.default_rng(seed))
    for i, v in enumerate(out):
        assert v.image.shape == (48, 64, 3) and v.depth.shape == (48, 64)
        err = lambda K, i=i, v=v: np.abs(_render(scene, i, K, 48, 64)[0].astype(float) - v.image).mean()  # noqa: E731
        ok = err(v.K)
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            K = v.K.copy()
            K[0, 2] += dx
            K[1, 2] += dy
            assert ok < 0.75 * err(K)


def test_crop_without_valid_depth_is_reported():
    _, views = _views()
    views[0].mask[:] = False
    with pytest.raises(InputError, match="no crop of the reference view has valid ground-truth depth"):
        ResizeCrop(max_tries=5)(views, 48, 64, np.random.default_rng(0), "scene X")


def test_photometric_factors_are_shared_by_the_views_and_seeded():
    img = torch.rand(1, 3, 16, 16)
    imgs = img.repeat(3, 1, 1, 1)
    aug = PhotometricAugment()
    a = aug(imgs, np.random.default_rng(5))
    assert torch.equal(a[0], a[1]) and torch.equal(a[1], a[2])
    assert not torch.allclose(a[0], img[0])
    assert torch.equal(a, aug(imgs, np.random.default_rng(5)))
    assert float(a.min()) >= 0 and float(a.max()) <= 1
