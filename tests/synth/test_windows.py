"""Training views as windows of high-resolution photos (``sensor_width``): exact crops, the photo's range."""

import dataclasses

import numpy as np
import pytest

from mvsformerpp.synth import random_scene, render_view
from mvsformerpp.synth.layouts import heldout_scene, training_scene
from mvsformerpp.synth.render import sensor_depth_range


def _whole_photo(scene, cam):
    """The camera of the whole photo a window was cut from, and the scene at the photo's size."""
    K, w, h = cam.sensor
    return dataclasses.replace(cam, K=K.copy(), sensor=None), dataclasses.replace(scene, width=w, height=h)


@pytest.mark.parametrize("build", [training_scene, heldout_scene])
def test_a_window_is_an_exact_crop_of_its_photo(build):
    scene = build(3, num_views=3, height=24, width=32, sensor_width=(96, 96))
    for cam in scene.cameras:
        K, w, h = cam.sensor
        assert (w, h) == (96, 72)
        x0, y0 = K[0, 2] - cam.K[0, 2], K[1, 2] - cam.K[1, 2]
        assert x0 == round(x0) and y0 == round(y0) and 0 <= x0 <= w - 32 and 0 <= y0 <= h - 24
        assert cam.K[0, 0] == K[0, 0] and cam.K[1, 1] == K[1, 1]
        _, depth, _ = render_view(scene, cam)
        full_cam, full_scene = _whole_photo(scene, cam)
        _, full, _ = render_view(full_scene, full_cam)
        crop = full[int(y0):int(y0) + 24, int(x0):int(x0) + 32]
        np.testing.assert_allclose(depth, crop, rtol=1e-6)


def test_windows_see_one_place_and_have_long_focal_lengths():
    for seed in range(8):
        scene = random_scene(seed, num_views=5, height=48, width=64, style="train", sensor_width=(600, 1200))
        K, w, _ = scene.cameras[0].sensor
        assert 600 <= w <= 1200 and K[0, 0] > 0.6 * w  # fields of view of 75 degrees at most
        hit = [(render_view(scene, c)[1] > 0).mean() for c in scene.cameras]
        assert np.median(hit) > 0.2, (seed, scene.meta["layout"], hit)  # the windows look at the anchor's surface


def test_without_sensor_width_scenes_are_unchanged():
    a = random_scene(7, num_views=3, height=24, width=32, style="train")
    b = random_scene(7, num_views=3, height=24, width=32, style="train", sensor_width=None)
    assert all(c.sensor is None for c in a.cameras)
    for ca, cb in zip(a.cameras, b.cameras):
        np.testing.assert_array_equal(ca.K, cb.K)
        np.testing.assert_array_equal(ca.R, cb.R)


def test_the_photo_depth_range_holds_the_windows_depths():
    scene = training_scene(5, num_views=3, height=48, width=64, layout="room", sensor_width=(400, 400))
    cam = scene.cameras[0]
    near, far = sensor_depth_range(scene, cam, percentiles=(0, 100))
    full_cam, full_scene = _whole_photo(scene, cam)
    _, full, _ = render_view(full_scene, full_cam)
    # a sparse grid of the photo: within a few % of the dense photo's extremes
    assert full[full > 0].min() <= near <= 1.1 * full[full > 0].min()
    assert 0.9 * full.max() <= far <= full.max()
    assert sensor_depth_range(scene, dataclasses.replace(cam, sensor=None)) is None


def test_bad_sensor_widths_are_refused():
    with pytest.raises(ValueError, match="sensor_width"):
        training_scene(1, 2, 24, 32, sensor_width=(0, 100))
    with pytest.raises(ValueError, match="sensor_width"):
        random_scene(1, 2, 24, 32, style="classic", sensor_width=(100, 200))


def test_written_window_scenes_load_as_photos_with_the_photo_range(tmp_path):
    from mvsformerpp.io.detect import load_scene
    from mvsformerpp.io.mvsnet import read_cam
    from mvsformerpp.io.pfm import read_pfm
    from mvsformerpp.synth import generate_scene

    out = generate_scene(tmp_path / "s", seed=4, num_views=3, height=48, width=64, style="train",
                         sensor_width=(900, 900), gt_points=2000)
    scene = load_scene(out)  # principal points in the middle: the loader's photo-and-camera check passes
    assert len(scene.views) == 3
    for i in range(3):
        cam = read_cam(out / "cams" / f"{i:08d}_cam.txt")
        assert abs(cam.K[0, 2] - 32) < 1e-6 and cam.K[0, 0] > 0.6 * 900
        depth = read_pfm(out / "depth_gt" / f"{i:08d}.pfm")
        assert cam.depth_min <= 0.95 * depth[depth > 0].min() + 1e-6
        assert cam.depth_max >= 1.05 * depth.max() - 1e-6
