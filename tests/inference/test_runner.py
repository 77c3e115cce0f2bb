import numpy as np
import pytest
import torch

from mvsformerpp.inference.resolution import plan_views
from mvsformerpp.inference.runner import SceneInference, select_sources, stage_projections
from mvsformerpp.io.scene import Scene, View


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def plane_scene(n=4, size=(200, 150)):
    """Cameras near the origin looking down +z at the world plane z = 5."""
    w, h = size
    K = np.array([[180.0, 0, w / 2 + 3.0], [0, 175.0, h / 2 - 2.0], [0, 0, 1]])
    views = []
    for i in range(n):
        R = rot_y(0.05 * (i - n / 2))
        C = np.array([0.3 * i, -0.1 * i, 0.0])
        views.append(View(name=f"v{i}", image_path=f"v{i}.png", width=w, height=h, K=K, R=R, t=-R @ C,
                          depth_min=3.0, depth_max=8.0, neighbors=[j for j in range(n) if j != i]))
    return Scene(views)


def plane_depth(view, z_plane=5.0):
    v, u = np.mgrid[0 : view.height, 0 : view.width]
    rays = np.stack([u + 0.5, v + 0.5, np.ones_like(u)], -1) @ np.linalg.inv(view.K).T
    nc = view.R @ np.array([0.0, 0.0, 1.0])
    return (z_plane + nc @ view.t) / (rays @ nc)


def make_runner(model, scene, cache_bytes, long_side=96, loads=None):
    """A runner over random photos; ``loads`` (a list) records the index of every photo it reads."""
    rng = np.random.default_rng(1)
    images = [rng.integers(0, 256, (v.height, v.width, 3), dtype=np.uint8) for v in scene.views]
    plans = plan_views([(v.width, v.height) for v in scene.views], long_side)

    def load(i):
        if loads is not None:
            loads.append(i)
        return images[i]

    return SceneInference(model, scene, plans, load, num_views=3, num_depth=16, cache_bytes=cache_bytes)


def test_depth_comes_back_at_original_resolution_with_exact_geometry(fake_model_cls):
    scene = plane_scene()
    runner = make_runner(fake_model_cls(plane_offset=5.0), scene, cache_bytes=1 << 20)
    for ref in range(len(scene)):
        res = runner.infer(ref)
        truth = plane_depth(scene.views[ref])
        assert res.depth.shape == (150, 200) and res.confidence.shape == (150, 200)
        # Interior pixels: bilinear resampling of a smooth depth field (2.08x upsampling).
        np.testing.assert_allclose(res.depth[3:-3, 3:-3], truth[3:-3, 3:-3], rtol=2e-3)
        assert 0 <= res.confidence.min() and res.confidence.max() <= 1


def test_cache_gives_identical_outputs_and_encodes_and_reads_each_image_once(fake_model_cls):
    scene = plane_scene(5)
    cached = fake_model_cls(plane_offset=5.0)
    plain = fake_model_cls(plane_offset=5.0)
    loads = []
    r1 = make_runner(cached, scene, cache_bytes=1 << 24, loads=loads)
    r2 = make_runner(plain, scene, cache_bytes=0)
    for ref in range(len(scene)):
        a, b = r1.infer(ref), r2.infer(ref)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.confidence, b.confidence)
    assert cached.encoded == len(scene)  # once per image
    assert plain.encoded == len(scene) * 3  # once per (reference, view) pair
    assert r1.cache.hits == len(scene) * 3 - len(scene)
    assert sorted(loads) == list(range(len(scene)))  # a cached image's photo is not read again


def test_source_selection_pads_by_repeating_the_best_neighbour():
    scene = plane_scene(3)
    scene.views[0].neighbors = [2]
    assert select_sources(scene, 0, 4) == [2, 2, 2]
    assert select_sources(scene, 1, 3) == [0, 2]
    scene.views[0].neighbors = []
    with pytest.raises(ValueError):
        select_sources(scene, 0, 3)


def test_stage_projection_layout():
    E = np.stack([np.eye(4), np.eye(4)])
    E[1, :3, 3] = [1, 2, 3]
    K = np.stack([np.array([[100.0, 0, 32], [0, 90, 24], [0, 0, 1]])] * 2)
    P = stage_projections(E, K)
    assert P["stage1"].shape == (1, 2, 2, 4, 4)
    assert torch.allclose(P["stage4"][0, 1, 0], torch.from_numpy(E[1]).float())
    assert torch.allclose(P["stage1"][0, 0, 1, 0, :3], torch.tensor([12.5, 0, 4]))
    assert P["stage2"][0, 0, 1, 2, 2] == 1
