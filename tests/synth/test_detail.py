"""Fine surface detail (``detail``): structure at the pixel scale that stays on the surface in every view."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter, map_coordinates

from mvsformerpp.synth import random_scene, render_view


def _fine_band(image: np.ndarray) -> np.ndarray:
    g = image.astype(np.float64).mean(-1) / 255.0
    return g - gaussian_filter(g, 1.0)


def _fine_band_match(scene) -> tuple[float, float]:
    """(std of view 0's finest band, NCC of that band against view 1's, warped through the exact depth on the
    pixels both views see): contrast at the pixel scale, and how much of it is the same surface in both."""
    (img0, d0, _), (img1, d1, _) = (render_view(scene, c) for c in scene.cameras[:2])
    c0, c1 = scene.cameras[:2]
    H, W = d0.shape
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    rays = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3) @ np.linalg.inv(c0.K).T
    world = (rays * d0.reshape(-1, 1) - c0.t) @ c0.R
    p = world @ c1.R.T + c1.t
    uv = p @ c1.K.T
    u, v = uv[:, 0] / uv[:, 2] - 0.5, uv[:, 1] / uv[:, 2] - 0.5
    ok = (d0.reshape(-1) > 0) & (p[:, 2] > 0) & (u > 1) & (v > 1) & (u < W - 2) & (v < H - 2)
    seen = map_coordinates(d1, [v, u], order=0, mode="nearest")
    ok &= np.abs(seen - p[:, 2]) < 0.01 * p[:, 2]
    a = _fine_band(img0).reshape(-1)[ok]
    b = map_coordinates(_fine_band(img1), [v, u], order=1, mode="nearest")[ok]
    a, b = a - a.mean(), b - b.mean()
    return float(a.std()), float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_detail_changes_colour_only():
    plain = random_scene(5, num_views=2, height=48, width=64, style="train", sensor_width=(600, 1600))
    rich = random_scene(5, num_views=2, height=48, width=64, style="train", sensor_width=(600, 1600), detail=1.0)
    for a, b in zip(plain.cameras, rich.cameras):
        img_a, depth_a, _ = render_view(plain, a)
        img_b, depth_b, _ = render_view(rich, b)
        np.testing.assert_array_equal(depth_a, depth_b)
        assert np.abs(img_a.astype(int) - img_b.astype(int)).mean() > 0.5
    again = random_scene(5, num_views=2, height=48, width=64, style="train", sensor_width=(600, 1600), detail=1.0)
    np.testing.assert_array_equal(render_view(rich, rich.cameras[0])[0], render_view(again, again.cameras[0])[0])


def test_detail_adds_pixel_scale_contrast_that_every_view_sees():
    plain, rich = [], []
    for seed in range(6):
        for out, detail in ((plain, 0.0), (rich, 1.0)):
            scene = random_scene(300 + seed, num_views=3, height=64, width=80, style="train",
                                 sensor_width=(1200, 2400), detail=detail)
            out.append(_fine_band_match(scene))
    plain, rich = np.array(plain), np.array(rich)
    # magnified textures are smooth at the pixel scale, so their finest band is mostly per-view sensor noise;
    # the detail layer puts surface structure there: the same in both views ...
    assert np.median(rich[:, 1]) > np.median(plain[:, 1]) + 0.2 and np.median(rich[:, 1]) > 0.5
    # ... and more contrast that both views share (std x correlation)
    shared = lambda r: np.median(r[:, 0] * np.clip(r[:, 1], 0, None))  # noqa: E731
    assert shared(rich) > 1.5 * shared(plain)


def test_bad_detail_is_refused():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="detail"):
            random_scene(0, num_views=2, height=32, width=32, style="train", detail=bad)
    with pytest.raises(ValueError, match="detail need style"):
        random_scene(0, num_views=2, height=32, width=32, detail=0.5)
