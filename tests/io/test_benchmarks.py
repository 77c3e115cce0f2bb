import shutil

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import InputError
from mvsformerpp.io.benchmarks import list_dtu_scans, load_blended_scene, load_dtu_scene, load_tnt_scene
from mvsformerpp.io.mvsnet import write_cam, write_pair
from mvsformerpp.io.pfm import read_pfm, write_pfm

from .fakes import DTU_PAIR, blended_cam, make_dtu


def test_dtu_training_layout_with_real_views(tmp_path):
    root = make_dtu(tmp_path / "dtu")
    scene = load_dtu_scene(root).validate()
    assert scene.source_format == "dtu" and [v.name for v in scene.views] == ["00000000", "00000001"]
    v0, v1 = scene.views
    assert (v0.width, v0.height) == (640, 512)
    assert v0.neighbors == [1] and v1.neighbors == [0]  # view 5 has no photo: dropped from the pairs
    assert v0.depth_min == 425.0
    d0, d1 = read_pfm(v0.depth_gt_path), read_pfm(v1.depth_gt_path)
    assert d0.shape == (128, 160) and v0.mask_path is None
    # Independent check of the cameras: GT depth of view 0, lifted to 3-D and projected into view 1,
    # agrees with view 1's own GT depth (depth maps are at 1/4 of the photo resolution).
    K0, K1 = v0.K.copy(), v1.K.copy()
    K0[:2] /= 4
    K1[:2] /= 4
    ys, xs = np.nonzero(d0 > 0)
    pix = np.stack([xs, ys, np.ones_like(xs)]).astype(float)
    X = v0.R.T @ (np.linalg.inv(K0) @ pix * d0[ys, xs] - v0.t[:, None])
    p = K1 @ (v1.R @ X + v1.t[:, None])
    u, w = np.round(p[0] / p[2]).astype(int), np.round(p[1] / p[2]).astype(int)
    inside = (u >= 0) & (u < 160) & (w >= 0) & (w < 128)
    d1s = d1[w[inside], u[inside]]
    ok = d1s > 0
    err = np.abs(p[2][inside][ok] - d1s[ok])
    assert ok.sum() > 5000 and np.median(err) < 2.0  # millimetres
    # A wrong pose (the identity) does not agree.
    p_bad = K1 @ (X + v1.t[:, None])
    assert np.median(np.abs(p_bad[2] - np.median(d1[d1 > 0]))) > 20


def test_dtu_scan_choice_and_errors(tmp_path):
    root = make_dtu(tmp_path / "dtu", scans=("scan1", "scan10", "scan2"))
    assert list_dtu_scans(root) == ["scan1", "scan2", "scan10"]
    with pytest.raises(InputError, match="3 scans .*choose one"):
        load_dtu_scene(root)
    assert len(load_dtu_scene(root, scan=10)) == 2
    with pytest.raises(InputError, match="no photos for scan7"):
        load_dtu_scene(root, scan="scan7")
    with pytest.raises(InputError, match="light 5"):
        load_dtu_scene(root, scan=1, light=5)
    with pytest.raises(InputError, match="no raw photos"):
        load_dtu_scene(root, scan=1, resolution="raw")
    with pytest.raises(InputError, match="not a DTU"):
        load_dtu_scene(tmp_path)


def test_blendedmvs_nested_layout(tmp_path):
    pid = "5a3ca9cb270f0e3f14d0eddb"
    d = tmp_path / pid / pid / pid
    for i in range(2):
        write_cam(d / "cams" / f"{i:08d}_cam.txt", blended_cam(i))
        (d / "blended_images").mkdir(parents=True, exist_ok=True)
        shutil.copy(DTU_PAIR / f"rect_00{i + 1}_0_r5000.png", d / "blended_images" / f"{i:08d}.jpg")
        Image.new("RGB", (640, 512)).save(d / "blended_images" / f"{i:08d}_masked.jpg")
        write_pfm(d / "rendered_depth_maps" / f"{i:08d}.pfm", np.full((512, 640), 500.0 + i, np.float32))
    write_pair(d / "cams" / "pair.txt", {0: [(1, 5.0)], 1: [(0, 5.0)]})
    scene = load_blended_scene(tmp_path / pid).validate()
    assert scene.source_format == "blendedmvs" and len(scene) == 2
    assert scene.views[1].image_path.name == "00000001.jpg"
    assert read_pfm(scene.views[1].depth_gt_path)[0, 0] == 501.0
    assert (scene.views[0].depth_min, scene.views[0].depth_max) == (425.0, 935.0)
    np.testing.assert_allclose(scene.views[0].K, blended_cam(0).K)  # full-resolution K kept as is
    with pytest.raises(InputError, match="not a BlendedMVS"):
        load_blended_scene(tmp_path)


def test_tanks_and_temples_with_short_range_cameras(tmp_path):
    inter = tmp_path / "intermediate"
    scene_dir = inter / "Family"
    (scene_dir / "images").mkdir(parents=True)
    for i in range(3):
        cam = blended_cam(i % 2)
        write_cam(scene_dir / "cams" / f"{i:08d}_cam.txt", cam)
        cam.depth_min, cam.depth_max = 450.0, 800.0
        write_cam(inter / "short_range_cameras" / "cams_family" / f"{i:08d}_cam.txt", cam)
        Image.new("RGB", (640, 512)).save(scene_dir / "images" / f"{i:08d}.jpg")
    write_pair(scene_dir / "pair.txt", {0: [(1, 3.0), (2, 1.0)], 1: [(0, 3.0)], 2: [(0, 1.0)]})
    normal = load_tnt_scene(scene_dir).validate()
    short = load_tnt_scene(scene_dir, short_range=True).validate()
    assert normal.views[0].depth_min == 425.0 and short.views[0].depth_min == 450.0
    assert normal.views[0].neighbors == [1, 2] and short.views[2].neighbors == [0]
    assert all(v.depth_gt_path is None for v in normal.views)
    shutil.rmtree(inter / "short_range_cameras")
    with pytest.raises(InputError, match="short_range_cameras"):
        load_tnt_scene(scene_dir, short_range=True)
    (scene_dir / "cams").rename(scene_dir / "cams_1")
    assert len(load_tnt_scene(scene_dir)) == 3


def test_dtu_raw_resolution(tmp_path):
    root = tmp_path / "dtu"
    (root / "Rectified_raw" / "scan3").mkdir(parents=True)
    (root / "Depths_raw" / "scan3").mkdir(parents=True)
    for i in range(2):
        write_cam(root / "Cameras" / f"{i:08d}_cam.txt", blended_cam(i))  # K for the photo's own size
        shutil.copy(DTU_PAIR / f"rect_00{i + 1}_0_r5000.png", root / "Rectified_raw" / "scan3" /
                    f"rect_00{i + 1}_3_r5000.png")
        write_pfm(root / "Depths_raw" / "scan3" / f"depth_map_000{i}.pfm", np.ones((512, 640), np.float32))
        Image.new("L", (640, 512)).save(root / "Depths_raw" / "scan3" / f"depth_visual_000{i}.png")
    write_pair(root / "Cameras" / "pair.txt", {0: [(1, 1.0)], 1: [(0, 1.0)]})
    scene = load_dtu_scene(root).validate()  # only raw photos: "auto" picks them
    assert [v.image_path.parent.name for v in scene.views] == ["scan3", "scan3"]
    np.testing.assert_array_equal(scene.views[0].K, blended_cam(0).K)
    assert scene.views[1].mask_path.name == "depth_visual_0001.png"
    assert scene.views[1].depth_gt_path.parent.parent.name == "Depths_raw"
    with pytest.raises(InputError, match="no train photos"):
        load_dtu_scene(root, resolution="train")
