"""DTU and BlendedMVS training sets read small trees in their official layouts (built here from
synthetic scenes) and yield images, intrinsics and depths that agree: warping a source photo into the
reference with the ground-truth depth reproduces the reference photo."""

import dataclasses

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from PIL import Image

from mvsformerpp.data import ResizeCrop, SampleKey
from mvsformerpp.data.dtu import blended_entries, dtu_entries, dtu_list, read_list
from mvsformerpp.data.scenes import BalancedMix, SceneDataset
from mvsformerpp.errors import InputError
from mvsformerpp.io.mvsnet import MVSNetCam, write_cam
from mvsformerpp.io.pair import write_pair
from mvsformerpp.io.pfm import write_pfm
from mvsformerpp.models.inputs import IMAGENET_MEAN, IMAGENET_STD

from .train_utils import rendered_views

H, W, N = 96, 128, 4


def _render(seed=3):
    return rendered_views(seed, N, H, W)[1]


def _pairs():
    return {i: [(j, 1.0) for j in range(N) if j != i] for i in range(N)}


def _cam(K, E, depth):
    valid = depth[depth > 0]
    return MVSNetCam(E, K, float(valid.min()) * 0.9, float(valid.max()) * 1.1)


def make_dtu(root, scans=("scan1", "scan4"), lights=range(7)):
    views = _render()
    (root / "Cameras").mkdir(parents=True)
    write_pair(root / "Cameras" / "pair.txt", _pairs())
    for vid, (_, depth, K, E) in enumerate(views):
        write_cam(root / "Cameras" / f"{vid:08d}_cam.txt", _cam(K, E, depth))
    for scan in scans:
        (root / "Rectified_raw" / scan).mkdir(parents=True)
        (root / "Depths_raw" / scan).mkdir(parents=True)
        for vid, (image, depth, _, _) in enumerate(views):
            for light in lights:
                Image.fromarray(image).save(root / "Rectified_raw" / scan / f"rect_{vid + 1:03d}_{light}_r5000.png")
            write_pfm(root / "Depths_raw" / scan / f"depth_map_{vid:04d}.pfm", depth)
            Image.fromarray(((depth > 0) * 200).astype(np.uint8)).save(
                root / "Depths_raw" / scan / f"depth_visual_{vid:04d}.png")
    return root


def make_blended(root, pid="5a3ca9cb270f0e3f14d0eddb"):
    views = _render(seed=8)
    d = root / pid / pid / pid  # the nested release layout
    for sub in ("blended_images", "cams", "rendered_depth_maps"):
        (d / sub).mkdir(parents=True)
    write_pair(d / "cams" / "pair.txt", _pairs())
    for vid, (image, depth, K, E) in enumerate(views):
        Image.fromarray(image).save(d / "blended_images" / f"{vid:08d}.jpg", quality=98)
        write_cam(d / "cams" / f"{vid:08d}_cam.txt", _cam(K, E, depth))
        write_pfm(d / "rendered_depth_maps" / f"{vid:08d}.pfm", depth)
    return root, pid


def _photometric_warp_error(item, depth_scale=1.0):
    """Mean |ref - warped src| over valid reference pixels (images back in [0, 1])."""
    mean, std = torch.tensor(IMAGENET_MEAN).view(3, 1, 1), torch.tensor(IMAGENET_STD).view(3, 1, 1)
    imgs = item["imgs"] * std + mean
    P = item["proj_matrices"]["stage4"].double()
    depth = item["depth_gt"]["stage4"].double() * depth_scale
    mask = item["mask"]["stage4"] > 0.5
    h, w = depth.shape
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64) + 0.5, torch.arange(w, dtype=torch.float64) + 0.5,
                          indexing="ij")
    K0, E0 = P[0, 1, :3, :3], P[0, 0]
    rays = torch.stack([u, v, torch.ones_like(u)], -1) @ torch.linalg.inv(K0).T
    cam = rays * depth[..., None]
    world = (cam - E0[:3, 3]) @ E0[:3, :3]
    errs = []
    for s in range(1, imgs.shape[0]):
        K, E = P[s, 1, :3, :3], P[s, 0]
        pc = world @ E[:3, :3].T + E[:3, 3]
        uv = (pc @ K.T)[..., :2] / pc[..., 2:3]
        grid = torch.stack([uv[..., 0] / w * 2 - 1, uv[..., 1] / h * 2 - 1], -1)[None].float()
        warped = F.grid_sample(imgs[s][None], grid, align_corners=False)[0]
        inside = (grid[0].abs() <= 1).all(-1) & mask
        errs.append((warped - imgs[0]).abs().mean(0)[inside])
    return float(torch.cat(errs).median())


def test_dtu_layout_samples_agree_with_their_geometry(tmp_path):
    root = make_dtu(tmp_path / "dtu")
    lst = tmp_path / "scans.txt"
    lst.write_text("scan1\n4  # a comment\n")
    entries = dtu_entries(root, read_list(lst), lights=(0, 3, 6), list_path=lst)
    ds = SceneDataset(entries, num_views=3, resize_crop=ResizeCrop(scale_range=(1.0, 1.2), min_scale=0.5))
    assert len(ds) == 2 * 3 * N  # scans x lights x reference views
    for i in (0, 5, 17):
        item = ds[SampleKey(i, 64, 96, 0)]
        assert item["imgs"].shape == (3, 3, 64, 96) and item["depth_gt"]["stage1"].shape == (8, 12)
        good, off = _photometric_warp_error(item), _photometric_warp_error(item, depth_scale=1.08)
        assert good < 0.02 and good < 0.5 * off, (good, off)


def test_blended_layout_and_balanced_mix(tmp_path):
    root, pid = make_blended(tmp_path / "blended")
    b = SceneDataset(blended_entries(root, [pid]), num_views=3, resize_crop=ResizeCrop(min_scale=0.5))
    item = b[SampleKey(1, 64, 96, 0)]
    good, off = _photometric_warp_error(item), _photometric_warp_error(item, depth_scale=1.08)
    assert good < 0.03 and good < 0.5 * off, (good, off)
    d = SceneDataset(dtu_entries(make_dtu(tmp_path / "dtu", scans=("scan1",)), ["scan1"], lights=(3,)),
                     num_views=3, resize_crop=ResizeCrop(min_scale=0.5))
    mix = BalancedMix([b, d])
    assert len(mix) == 2 * N and [mix._locate(i)[0] for i in range(4)] == [0, 1, 0, 1]


def test_shipped_dtu_lists():
    train, val, test, trainval = (read_list(dtu_list(n)) for n in ("train", "val", "test", "trainval"))
    assert (len(train), len(val), len(test)) == (79, 18, 22)
    assert sorted(trainval) == sorted(train + val) and not set(trainval) & set(test)


def test_bad_layouts_name_what_is_missing(tmp_path):
    with pytest.raises(InputError, match="DTU data root not found"):
        dtu_entries(tmp_path / "nowhere", ["scan1"], (3,))
    root = make_dtu(tmp_path / "dtu", scans=("scan1",), lights=(3,))
    with pytest.raises(InputError, match=r"1 scan\(s\) \(listed in L\) are not in this DTU root: scan9 "
                                         r"\(expected Rectified_raw/scan9/\)"):
        dtu_entries(root, ["scan1", "scan9"], (3,), list_path="L")
    with pytest.raises(InputError, match="rect_001_5_r5000.png is missing"):
        dtu_entries(root, ["scan1"], (3, 5))
    (root / "Depths_raw" / "scan1" / "depth_map_0002.pfm").unlink()
    with pytest.raises(InputError, match="Depths_raw/scan1/depth_map_0002.pfm is missing"):
        dtu_entries(root, ["scan1"], (3,))
    with pytest.raises(InputError, match="not in this BlendedMVS root.*blended_images"):
        blended_entries(tmp_path, ["abc"])


def test_synthetic_range_margin_widens_each_end_by_a_drawn_fraction():
    from mvsformerpp.data import SyntheticDataset

    def ratios(ds, index, seed):
        vs = ds.load_views(index, np.random.default_rng(seed), 48, 64)
        true = vs.views[0].depth[vs.views[0].depth > 0]
        return vs.depth_min / float(true.min()), vs.depth_max / float(true.max())

    fixed = SyntheticDataset(2, num_views=3, views_per_scene=3)
    assert ratios(fixed, 0, 0) == pytest.approx((0.95, 1.05))
    wide = SyntheticDataset(2, num_views=3, views_per_scene=3, range_margin=(0.1, 0.3))
    drawn = [ratios(wide, 0, seed) for seed in range(6)]
    for near, far in drawn:
        assert 0.7 <= near <= 0.9 and 1.1 <= far <= 1.3
    assert len({round(n, 6) for n, _ in drawn}) == 6  # a new draw per sample, near and far independent
    assert any(abs((1 - n) - (f - 1)) > 0.01 for n, f in drawn)
    with pytest.raises(InputError, match="range_margin"):
        SyntheticDataset(2, num_views=3, views_per_scene=3, range_margin=(0.3, 0.1))


def test_blended_finetune_takes_a_dtu_list_for_part_of_dtu(tmp_path):
    """A user with two DTU scans fine-tunes on BlendedMVS + those scans (the 95-scan list would refuse)."""
    from mvsformerpp.training.config import RECIPES
    from mvsformerpp.training.datasets import build_datasets

    root, pid = make_blended(tmp_path / "blended")
    dtu = make_dtu(tmp_path / "dtu", scans=("scan1", "scan4"), lights=range(7))
    (tmp_path / "dtu.txt").write_text("scan1\nscan4\n")
    (tmp_path / "val.txt").write_text("scan4\n")
    cfg = dataclasses.replace(RECIPES["blended_finetune"], data_root=str(root), dtu_root=str(dtu))
    with pytest.raises(InputError, match="are not in this DTU root"):
        build_datasets(cfg)
    train, val = build_datasets(dataclasses.replace(cfg, dtu_train_list=str(tmp_path / "dtu.txt"),
                                                    dtu_val_list=str(tmp_path / "val.txt")))
    blended, dtu_part = train.datasets
    assert len(blended) == N and len(dtu_part) == 2 * N * len(cfg.light_ids)  # both scans, every light
    assert len(val) == N  # scan4, one light


def test_a_synthetic_reference_that_sees_nothing_hands_over_to_the_next_camera():
    """One camera of a random scene may see only sky: its samples take the scene's next camera as the
    reference instead of stopping a long run (a scene no camera sees anything of: the next scene), and so does
    one that sees next to nothing; a source whose scenes never show anything is an error."""
    from mvsformerpp.data import SyntheticDataset
    from mvsformerpp.data.synthetic import MIN_SEEN
    from mvsformerpp.synth import render_view
    from mvsformerpp.synth.render import Camera, Surface, SynthScene, look_at
    from mvsformerpp.synth.shapes import Sphere

    def one_blind(seed, num_views, height, width, blind=(1,)):
        """A textured ball seen from a ring; the ``blind`` cameras look away from it, at nothing."""
        ball = Surface(Sphere(np.zeros(3), 1.0), "noise", np.array([[0.1, 0.2, 0.3], [0.9, 0.8, 0.6]]), seed)
        K = np.array([[40.0, 0, width / 2], [0, 40.0, height / 2], [0, 0, 1]])
        cams = []
        for i in range(num_views):
            c = 4 * np.array([np.cos(0.3 * i), np.sin(0.3 * i), 0.2])
            R, t = look_at(c, 2 * c if i in blind else np.zeros(3))
            cams.append(Camera(K, R, t))
        return SynthScene([ball], cams, width, height)

    ds = SyntheticDataset(1, num_views=3, views_per_scene=4, source=one_blind)
    handed = ds.load_views(1, np.random.default_rng(0), 24, 32)  # sample 1: camera 1 is blind
    normal = ds.load_views(2, np.random.default_rng(0), 24, 32)  # sample 2: camera 2, as the hand-over
    assert (handed.views[0].depth > 0).any()
    np.testing.assert_array_equal(handed.views[0].depth, normal.views[0].depth)
    np.testing.assert_array_equal(handed.views[0].E, normal.views[0].E)

    def one_far(seed, num_views, height, width):
        """Camera 1 sees the ball from so far that it covers a few pixels: next to nothing to crop or learn."""
        scene = one_blind(seed, num_views, height, width, blind=())
        c = 30 * np.array([np.cos(0.3), np.sin(0.3), 0.2])
        scene.cameras[1] = Camera(scene.cameras[1].K, *look_at(c, np.zeros(3)))
        return scene

    far = SyntheticDataset(1, num_views=3, views_per_scene=4, source=one_far)
    seen = far.load_views(1, np.random.default_rng(0), 24, 32).views[0]
    assert 0 < (render_view(one_far(1, 4, 24, 32), one_far(1, 4, 24, 32).cameras[1])[1] > 0).mean() < MIN_SEEN
    assert (seen.depth > 0).mean() >= MIN_SEEN
    np.testing.assert_array_equal(seen.E, far.load_views(2, np.random.default_rng(0), 24, 32).views[0].E)

    blind = SyntheticDataset(1, num_views=3, views_per_scene=3,
                             source=lambda **kw: one_blind(**kw, blind=range(kw["num_views"])))
    with pytest.raises(InputError, match="and the 7 scenes after it: no camera sees enough"):
        blind.load_views(0, np.random.default_rng(0), 24, 32)


def test_a_synthetic_scene_s_views_are_rendered_once_for_its_samples_in_a_row(monkeypatch):
    """Samples of one scene in a row (``synthetic_scene_batches``) share its renderings: every view rendered
    once, and each sample exactly what a process that rendered it afresh gives."""
    import mvsformerpp.synth as synth
    from mvsformerpp.data import SyntheticDataset

    def fresh(index):
        return SyntheticDataset(2, num_views=3, views_per_scene=4).load_views(index, np.random.default_rng(index),
                                                                              48, 64)

    expected = [fresh(i) for i in range(4)]
    rendered = []
    real = synth.render_view
    monkeypatch.setattr(synth, "render_view", lambda scene, cam: rendered.append(cam) or real(scene, cam))
    ds = SyntheticDataset(2, num_views=3, views_per_scene=4)
    got = [ds.load_views(i, np.random.default_rng(i), 48, 64) for i in range(4)]
    assert len(rendered) == 4  # one scene, four cameras, each rendered once for the four samples
    for a, b in zip(got, expected):
        assert (a.depth_min, a.depth_max) == (b.depth_min, b.depth_max)
        for va, vb in zip(a.views, b.views):
            np.testing.assert_array_equal(va.image, vb.image)
            np.testing.assert_array_equal(va.E, vb.E)
    ds.load_views(4, np.random.default_rng(0), 48, 64)  # the next scene
    ds.load_views(0, np.random.default_rng(0), 48, 96)  # another size: another rendering
    assert len(rendered) > 4 + 3
