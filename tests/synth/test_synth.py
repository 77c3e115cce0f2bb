"""The synthetic scenes have exact ground truth and are deterministic."""

import numpy as np
import pytest
import torch

from mvsformerpp.cli import main
from mvsformerpp.geometry.camera import depth_to_points, project
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_points, read_ply
from mvsformerpp.synth import generate_scene


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return generate_scene(tmp_path_factory.mktemp("synth") / "s", seed=3, num_views=5, height=96, width=128)


def test_layout_loads_as_mvsnet_scene(scene_dir):
    scene = load_scene(scene_dir)
    assert len(scene) == 5 and scene.source_format == "mvsnet"
    for i, v in enumerate(scene.views):
        depth = read_pfm(scene_dir / "depth_gt" / f"{i:08d}.pfm")
        assert depth.shape == (96, 128) and (v.width, v.height) == (128, 96)
        assert v.depth_min < depth[depth > 0].min() and depth.max() < v.depth_max
        assert len(v.neighbors) == 4 and i not in v.neighbors


def test_gt_depth_reprojects_exactly_into_neighbours(scene_dir):
    """Back-project view 0's GT depth, project into view 1: where visible, view 1's GT depth agrees."""
    scene = load_scene(scene_dir)
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    d0 = t(read_pfm(scene_dir / "depth_gt/00000000.pfm"))
    d1 = t(read_pfm(scene_dir / "depth_gt/00000001.pfm"))
    v0, v1 = scene.views[0], scene.views[1]
    pts = depth_to_points(d0, t(v0.K), t(v0.extrinsic)).reshape(-1, 3)
    u, v, z = project(t(v1.K), t(v1.extrinsic), pts)
    # Points that land exactly on a pixel centre of view 1 are rare, so compare at view 1's pixel
    # centres by ray casting the same scene: re-render view 1's depth at the projected coordinates.
    from mvsformerpp.synth import random_scene
    from mvsformerpp.synth.render import cast

    synth = random_scene(3, 5, 96, 128)
    cam = synth.cameras[1]
    inside = (u >= 0) & (u < 128) & (v >= 0) & (v < 96)
    uv1 = torch.stack([u, v, torch.ones_like(u)], 1)[inside].numpy()
    dirs = uv1 @ np.linalg.inv(cam.K).T @ cam.R
    t_hit, _, _ = cast(synth, np.broadcast_to(cam.center, dirs.shape), dirs)
    zi = z[inside].numpy()
    visible = np.abs(t_hit - zi) < 1e-6 * zi
    assert visible.mean() > 0.6  # most of view 0 is seen by its neighbour...
    assert (t_hit[~visible] < zi[~visible]).all()  # ...and the rest is occluded, never off the surface
    # The rendered GT of view 1 itself: at pixel centres the projection of its own GT reproduces it.
    pts1 = depth_to_points(d1, t(v1.K), t(v1.extrinsic)).reshape(-1, 3)
    u1, vv1, z1 = project(t(v1.K), t(v1.extrinsic), pts1)
    np.testing.assert_allclose(z1.numpy(), d1.reshape(-1).numpy(), rtol=1e-6)
    np.testing.assert_allclose(u1.numpy() % 1, 0.5, atol=1e-6)
    # Nearest-pixel agreement of the two GT maps where the point is visible (< 1e-4 relative
    # wherever the surface is smooth at pixel scale: the median error is far below that).
    ui, vi = u[inside].floor().long().numpy(), v[inside].floor().long().numpy()
    near = np.abs(u[inside].numpy() - (ui + 0.5)) + np.abs(v[inside].numpy() - (vi + 0.5)) < 0.05
    sel = visible & near
    rel = np.abs(d1.numpy()[vi[sel], ui[sel]] - z[inside].numpy()[sel]) / z[inside].numpy()[sel]
    assert sel.sum() > 20 and np.median(rel) < 1e-3


def test_deterministic_and_seed_dependent(tmp_path):
    a = generate_scene(tmp_path / "a", seed=5, num_views=2, height=64, width=64)
    b = generate_scene(tmp_path / "b", seed=5, num_views=2, height=64, width=64)
    c = generate_scene(tmp_path / "c", seed=6, num_views=2, height=64, width=64)
    for name in ("images/00000001.png", "depth_gt/00000001.pfm", "cams/00000001_cam.txt", "gt_surface.ply"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert (a / "images/00000001.png").read_bytes() != (c / "images/00000001.png").read_bytes()


def test_gt_surface_points_lie_on_the_depth_maps(scene_dir):
    pts = ply_points(read_ply(scene_dir / "gt_surface.ply"))
    assert len(pts) > 10_000 and np.isfinite(pts).all()


def test_cli_writes_a_dataset(tmp_path, capsys):
    assert main(["synth", str(tmp_path / "d"), "--scenes", "2", "--views", "3", "--height", "64", "--width", "64"]) == 0
    assert (tmp_path / "d/scenes.txt").read_text().split() == ["scene_0000", "scene_0001"]
    assert (tmp_path / "d/scene_0001/depth_gt/00000002.pfm").is_file()
    assert main(["synth", str(tmp_path / "e"), "--views", "1"]) == 2
