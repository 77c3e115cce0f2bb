"""LLFF poses_bounds.npy and IDR/NeuS cameras_sphere.npz: known cameras written in each layout, read back,
checked by projecting known 3-D points to the pixel positions the original cameras give."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import InputError
from mvsformerpp.io import detect_layout, load_scene
from mvsformerpp.io.idr import decompose_projection
from mvsformerpp.synth.render import look_at

W, H = 80, 60


def _cameras(n: int = 4, seed: int = 0):
    """n cameras on an arc around the origin: (K, R, t) world-to-camera, x right, y down, z forward."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = np.deg2rad(-30 + 20 * i)
        c = np.array([4 * np.cos(a), 4 * np.sin(a), 1.0 + 0.2 * i])
        R, t = look_at(c, rng.normal(0, 0.1, 3))
        f = 70.0 + i
        K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
        cams.append((K, R, t))
    return cams


POINTS = np.random.default_rng(1).uniform(-0.8, 0.8, (20, 3))


def _project(K, R, t, X):
    x = (X @ R.T + t) @ K.T
    return x[:, :2] / x[:, 2:], (X @ R.T + t)[:, 2]


def _photos(folder, n, w=W, h=H):
    folder.mkdir(parents=True)
    for i in range(n):
        Image.new("RGB", (w, h)).save(folder / f"{i:03d}.png")


def _llff(root, cams, w=W, h=H):
    rows = []
    for K, R, t in cams:
        c2w, C = R.T, -R.T @ t
        m = np.stack([c2w[:, 1], c2w[:, 0], -c2w[:, 2], C, [H, W, K[0, 0]]], axis=1)  # (down, right, back)
        z = _project(K, R, t, POINTS)[1]
        rows.append(np.concatenate([m.ravel(), [z.min(), z.max()]]))
    np.save(root / "poses_bounds.npy", np.array(rows))
    _photos(root / "images", len(cams), w, h)


def _idr(root, cams, scale=-3.7):
    data = {}
    S = np.diag([1.5, 1.5, 1.5, 1.0])  # the unit sphere scaled to radius 1.5 around (0.1, 0, 0)
    S[:3, 3] = [0.1, 0, 0]
    for i, (K, R, t) in enumerate(cams):
        P = np.eye(4)
        P[:3] = scale * (K @ np.hstack([R, t[:, None]]))  # any non-zero multiple is the same camera
        data[f"world_mat_{i}"], data[f"scale_mat_{i}"] = P, S
    np.savez(root / "cameras_sphere.npz", **data)
    _photos(root / "image", len(cams))


@pytest.mark.parametrize("layout", ["llff", "idr"])
def test_cameras_project_points_where_the_originals_do(tmp_path, layout):
    cams = _cameras()
    (_llff if layout == "llff" else _idr)(tmp_path, cams)
    assert detect_layout(tmp_path) == layout
    scene = load_scene(tmp_path)
    assert scene.source_format == layout and len(scene) == len(cams)
    for v, (K, R, t) in zip(scene.views, cams):
        expected, z = _project(K, R, t, POINTS)
        got, gz = _project(v.K, v.R, v.t, POINTS)
        assert np.abs(got - expected).max() < 1e-6 and np.abs(gz - z).max() < 1e-9
        assert v.depth_min <= z.min() and z.max() <= v.depth_max  # every point inside the view's range
        assert v.neighbors and (v.width, v.height) == (W, H)


def test_idr_depth_range_is_the_sphere(tmp_path):
    cams = _cameras()
    _idr(tmp_path, cams)
    v = load_scene(tmp_path / "cameras_sphere.npz").views[1]
    zc = (v.R @ np.array([0.1, 0, 0]) + v.t)[2]
    assert np.isclose(v.depth_min, zc - 1.5) and np.isclose(v.depth_max, zc + 1.5)


def test_llff_photos_at_another_resolution_scale_the_intrinsics(tmp_path):
    cams = _cameras()
    _llff(tmp_path, cams, w=W // 2, h=H // 2)
    scene = load_scene(tmp_path / "poses_bounds.npy")
    for v, (K, R, t) in zip(scene.views, cams):
        assert np.abs(_project(v.K, v.R, v.t, POINTS)[0] - _project(K, R, t, POINTS)[0] / 2).max() < 1e-6


def test_decomposition_recovers_the_camera():
    K, R, t = _cameras()[2]
    for scale in (1.0, -2.0, 1e-3):
        K2, R2, t2 = decompose_projection(scale * K @ np.hstack([R, t[:, None]]))
        assert np.allclose(K2, K) and np.allclose(R2, R) and np.allclose(t2, t)


@pytest.mark.parametrize("case, expect", [
    ("llff_count", "do not fit the images"),
    ("llff_aspect", "another aspect ratio"),
    ("llff_shape", r"\[N, 17\]"),
    ("idr_count", "do not fit the images"),
    ("idr_no_photos", "no photos"),
])
def test_cameras_that_do_not_fit_their_images(tmp_path, case, expect):
    cams = _cameras()
    if case == "llff_count":
        _llff(tmp_path, cams)
        (tmp_path / "images" / "000.png").unlink()
    elif case == "llff_aspect":
        _llff(tmp_path, cams, w=W, h=W)
    elif case == "llff_shape":
        _llff(tmp_path, cams)
        np.save(tmp_path / "poses_bounds.npy", np.zeros((4, 15)))
    elif case == "idr_count":
        _idr(tmp_path, cams)
        Image.new("RGB", (W, H)).save(tmp_path / "image" / "999.png")
    else:
        _idr(tmp_path, cams)
        for p in (tmp_path / "image").iterdir():
            p.unlink()
    with pytest.raises(InputError, match=expect):
        load_scene(tmp_path)
