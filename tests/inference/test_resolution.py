import numpy as np
import pytest
import torch

from mvsformerpp.inference.resolution import (
    BYTES_PER_PIXEL_PER_VIEW,
    MULTIPLE,
    choose_long_side,
    plan_views,
)


@pytest.mark.parametrize("size", [(640, 480), (480, 640), (1000, 333), (97, 1201), (64, 64)])
def test_plan_keeps_aspect_and_pads_to_the_network_multiple(size):
    (p,) = plan_views([size], 500)
    w, h = size
    assert p.canvas_width % MULTIPLE == 0 and p.canvas_height % MULTIPLE == 0
    assert p.resized_width <= p.canvas_width < p.resized_width + MULTIPLE
    assert p.resized_height <= p.canvas_height < p.resized_height + MULTIPLE
    assert max(p.resized_width, p.resized_height) <= max(500, 1)
    # Rounding to whole pixels moves the aspect ratio by less than one pixel's worth.
    assert abs(p.resized_width / p.resized_height - w / h) <= w / h * (1 / p.resized_height + 1 / p.resized_width)
    if max(w, h) <= 500:
        assert (p.resized_width, p.resized_height) == (w, h)  # never upscaled


def test_scaled_intrinsics_project_to_scaled_pixels():
    (p,) = plan_views([(640, 480)], 320)
    K = np.array([[1520.4, 0, 302.32], [0, 1525.9, 246.87], [0, 0, 1]])
    X = np.array([[0.1, -0.05, 2.0], [-0.3, 0.2, 3.0]]).T
    uv = (K @ X)[:2] / X[2]
    uv2 = (p.scale_intrinsics(K) @ X)[:2] / X[2]
    np.testing.assert_allclose(uv2[0], uv[0] * 320 / 640)
    np.testing.assert_allclose(uv2[1], uv[1] * 240 / 480)


def test_image_round_trip_through_canvas():
    rng = np.random.default_rng(0)
    (p,) = plan_views([(150, 70)], 1000)
    img = rng.integers(0, 256, (70, 150, 3), dtype=np.uint8)
    x = p.image_to_canvas(img)
    assert x.shape == (3, 96, 160)
    back = p.canvas_to_original(x[0])
    np.testing.assert_allclose(back.numpy(), img[..., 0] / 255.0, atol=1e-6)
    # Padding replicates the last column/row.
    assert torch.equal(x[:, :70, 150:], x[:, :70, 149:150].expand(-1, -1, 10))


def test_canvas_to_original_resizes_a_smooth_map():
    (p,) = plan_views([(400, 300)], 200)
    assert (p.resized_width, p.resized_height) == (200, 150)
    # f = u + 2v at pixel centres is linear, so bilinear resampling must reproduce it (away from borders).
    v, u = torch.meshgrid(torch.arange(256.0), torch.arange(256.0), indexing="ij")
    canvas = (u + 0.5) / 0.5 + 2 * (v + 0.5) / 0.5
    out = p.canvas_to_original(canvas).numpy()
    vv, uu = np.mgrid[0:300, 0:400]
    truth = (uu + 0.5) + 2 * (vv + 0.5)
    np.testing.assert_allclose(out[2:-2, 2:-2], truth[2:-2, 2:-2], rtol=1e-5)


def test_photos_whose_sides_are_multiples_of_32_are_not_padded():
    """The network needs multiples of 32 (its stage-1 token patches are 32 pixels): 640x480 photos run
    on a 640x480 canvas, with no rows of padding computed and cropped away."""
    (p,) = plan_views([(640, 480)], 640)
    assert (p.canvas_width, p.canvas_height) == (640, 480)
    (p,) = plan_views([(1600, 1200)], 1600)
    assert (p.canvas_width, p.canvas_height) == (1600, 1216)


def test_shared_canvas_for_mixed_sizes():
    plans = plan_views([(640, 480), (480, 640)], 640)
    assert {(p.canvas_width, p.canvas_height) for p in plans} == {(640, 640)}


def test_choose_long_side_respects_cap_and_memory():
    sizes = [(1600, 1200)]
    assert choose_long_side(sizes, 5, None, None) == 1600
    assert choose_long_side(sizes, 5, 800, None) == 800
    budget = 640 * 512 * 5 * BYTES_PER_PIXEL_PER_VIEW
    side = choose_long_side(sizes, 5, None, budget)
    (p,) = plan_views(sizes, side)
    assert p.canvas_width * p.canvas_height * 5 * BYTES_PER_PIXEL_PER_VIEW <= budget
    (bigger,) = plan_views(sizes, side + MULTIPLE)
    assert bigger.canvas_width * bigger.canvas_height * 5 * BYTES_PER_PIXEL_PER_VIEW > budget
    assert choose_long_side(sizes, 5, None, 1.0) == MULTIPLE  # floor


def test_depth_upsampling_invents_no_depth_between_surfaces():
    """A step from 1 m to 3 m (an occlusion edge) stays a step at the original size, with each pixel's
    confidence from the same side as its depth; a smooth slanted surface is interpolated, not staircased."""
    (p,) = plan_views([(400, 300)], 200)
    v, u = torch.meshgrid(torch.arange(256.0), torch.arange(256.0), indexing="ij")
    step = torch.where(u < 77.5, 1.0, 3.0)
    conf = torch.where(u < 77.5, 0.9, 0.2)
    depth, confidence = p.depth_to_original(step, conf)
    assert depth.shape == (300, 400) and confidence.shape == (300, 400)
    assert set(depth.unique().tolist()) == {1.0, 3.0}
    torch.testing.assert_close(confidence, torch.where(depth == 1.0, 0.9, 0.2))
    assert (depth[:, :150] == 1.0).all() and (depth[:, 160:] == 3.0).all()  # the edge near u = 155
    # A steep slanted surface (depth steps of 3-10% per canvas pixel): bilinear, as canvas_to_original.
    slanted = 0.3 + 0.03 * u + 0.01 * v
    depth, _ = p.depth_to_original(slanted, conf)
    torch.testing.assert_close(depth, p.canvas_to_original(slanted))
    assert len(depth[0].unique()) > 300  # not a staircase of the 200 canvas columns
