"""Tanks-and-Temples: crop volume, voxel downsampling, alignment, .log files and submission folders."""

import json
from collections import defaultdict

import numpy as np
import pytest

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.evaluation import (
    evaluate_tnt,
    evaluate_tnt_points,
    load_crop_volume,
    package_tnt_submission,
    read_log,
    voxel_downsample,
    write_log,
)
from mvsformerpp.evaluation.tnt import CropVolume, scene_threshold
from mvsformerpp.evaluation.tnt_submission import scene_poses
from mvsformerpp.io.ply import write_ply
from mvsformerpp.io.scene import Scene, View


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_voxel_downsample_matches_brute_force():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, size=(2000, 3))
    voxel = 0.3
    origin = pts.min(0) - voxel / 2
    groups = defaultdict(list)
    for p in pts:
        groups[tuple(np.floor((p - origin) / voxel).astype(int))].append(p)
    expected = np.array([np.mean(groups[k], axis=0) for k in sorted(groups)])
    np.testing.assert_allclose(voxel_downsample(pts, voxel), expected, atol=1e-12)
    np.testing.assert_allclose(voxel_downsample(pts[::-1], voxel), expected, atol=1e-12)  # order-free


def write_crop(path, axis="Z"):
    # An L-shaped polygon in x,y (area 3 of the square [0,2]^2 minus the [1,2]x[1,2] corner), z in [-1, 1].
    poly = [[0, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [1, 2, 0], [0, 2, 0]]
    path.write_text(json.dumps({"class_name": "SelectionPolygonVolume", "orthogonal_axis": axis,
                                "axis_min": -1.0, "axis_max": 1.0, "bounding_polygon": poly, "version_major": 1}))
    return path


def test_crop_volume_matches_analytic_region(tmp_path):
    crop = load_crop_volume(write_crop(tmp_path / "c.json"))
    rng = np.random.default_rng(1)
    pts = rng.uniform(-0.5, 2.5, size=(5000, 3))
    x, y, z = pts.T
    expected = (x > 0) & (y > 0) & (x < 2) & (y < 2) & ~((x > 1) & (y > 1)) & (z >= -1) & (z <= 1)
    np.testing.assert_array_equal(crop.contains(pts), expected)
    (tmp_path / "bad.json").write_text(json.dumps({"orthogonal_axis": "Z"}))
    with pytest.raises(FormatError, match="bounding_polygon"):
        load_crop_volume(tmp_path / "bad.json")


def test_aligned_copy_scores_perfectly_and_offset_fails(tmp_path):
    rng = np.random.default_rng(2)
    gt = rng.uniform(0, 1.9, size=(20000, 3)) * [1, 1, 0.2]
    # The prediction lives in another frame: gt = s R pred + t.
    s, R, t = 1.7, rotation([1, 2, 3], 0.4), np.array([0.5, -2, 3])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = s * R, t
    pred = (gt - t) @ R / s
    res = evaluate_tnt_points(pred, gt, 0.01, alignment=T)
    assert res.metrics.precision == 1.0 and res.metrics.recall == 1.0
    unaligned = evaluate_tnt_points(pred, gt, 0.01)
    assert unaligned.metrics.f_score < 0.2

    # Cropped: only points inside the L-shaped prism are evaluated; extra prediction outside is ignored.
    write_ply(tmp_path / "gt.ply", gt)
    write_ply(tmp_path / "pred.ply", np.concatenate([pred, (np.array([[5.0, 5, 0]]) - t) @ R / s]))
    np.savetxt(tmp_path / "trans.txt", T)
    res = evaluate_tnt(tmp_path / "pred.ply", tmp_path / "gt.ply", scene="Ignatius",
                       crop_json=write_crop(tmp_path / "c.json"), alignment_txt=tmp_path / "trans.txt")
    assert res.metrics.threshold == 0.003
    assert res.metrics.precision > 0.999 and res.metrics.recall > 0.999  # float32 PLY rounding only
    assert res.pred_points[:, :2].max() < 2.0


def test_thresholds_and_errors():
    assert scene_threshold("Barn", None) == 0.01
    assert scene_threshold("Barn", 0.02) == 0.02
    with pytest.raises(InputError, match="give one with --threshold"):
        scene_threshold("Lighthouse2", None)
    square = CropVolume(2, -1, 1, np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]]))
    with pytest.raises(InputError, match="crop volume"):
        evaluate_tnt_points(np.ones((3, 3)) * 9, np.zeros((3, 3)) + 0.5, 0.1,
                            crop=square)


def test_log_round_trip_scene_poses_and_package(tmp_path):
    views = []
    for i in range(3):
        R = rotation([0, 1, 0.2 * i], 0.3 * i + 0.1)
        views.append(View(name=f"{i:03d}", image_path=tmp_path / f"{i}.png", width=4, height=3, K=np.eye(3),
                          R=R, t=np.array([i, 1.0, 2.0])))
    scene = Scene(views=views)
    poses = scene_poses(scene)
    for v, P in zip(views, poses):
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = v.R, v.t
        np.testing.assert_allclose(P @ w2c, np.eye(4), atol=1e-12)
    write_log(tmp_path / "a.log", poses)
    np.testing.assert_allclose(read_log(tmp_path / "a.log"), poses, atol=1e-9)
    assert (tmp_path / "a.log").read_text().splitlines()[5] == "1 1 0"

    write_ply(tmp_path / "rec.ply", np.zeros((2, 3)))
    out = package_tnt_submission(tmp_path / "sub", {"Family": (tmp_path / "rec.ply", scene)})
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["Family.log", "Family.ply"]
    assert (out / "Family.ply").read_bytes() == (tmp_path / "rec.ply").read_bytes()
    with pytest.raises(InputError, match="already packaged"):
        package_tnt_submission(out, {"Family": (tmp_path / "rec.ply", poses)})
    with pytest.raises(InputError, match="does not exist"):
        package_tnt_submission(out, {"Horse": (tmp_path / "none.ply", poses)})
    (tmp_path / "bad.log").write_text("0 0 0\n1 0 0 0\n")
    with pytest.raises(FormatError, match="blocks of 5"):
        read_log(tmp_path / "bad.log")
