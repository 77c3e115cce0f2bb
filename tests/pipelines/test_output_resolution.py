"""``--output-resolution working``: maps at the working size, images and cameras scaled to match, fused alike."""

import importlib.util
import sys
from pathlib import Path

import numpy as np

from mvsformerpp.io.images import image_size
from mvsformerpp.io.mvsnet import read_cam
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_points, read_ply
from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct
from mvsformerpp.synth.strip import generate_strip_scene


def plane_model():
    """The test stand-in network, answering the exact depth of the strip scene's plane z = 10 + 0.05 x."""
    name = "outres_fake_model"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).parents[1] / "inference" / "fake_model.py")
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name].FakeMVSModel(plane_normal=(-0.05, 0.0, 1.0), plane_offset=10.0)


def test_working_resolution_outputs_fuse_onto_the_plane(tmp_path):
    scene = generate_strip_scene(tmp_path / "scene", num_views=5, height=96, width=128, with_depth_maps=False)
    clouds = {}
    for mode in ("working", "original"):
        cfg = ReconstructConfig(preset="lite", max_size=64, num_views=3, cache_mb=16, fusion="normal",
                                output_resolution=mode, fusion_resolution="original")  # fuse the maps as written
        out = tmp_path / mode
        summary = reconstruct(scene, out, cfg, quiet=True, model=plane_model())
        h, w = (48, 64) if mode == "working" else (96, 128)
        assert read_pfm(out / "depth_est" / "00000002.pfm").shape == (h, w)
        assert read_pfm(out / "confidence" / "00000002.pfm").shape == (h, w)
        assert image_size(out / "images" / "00000002.png") == (w, h)
        K = read_cam(out / "cams" / "00000002_cam.txt").K
        K0 = read_cam(scene / "cams" / "00000002_cam.txt").K
        np.testing.assert_allclose(K, np.diag([w / 128, h / 96, 1.0]) @ K0, rtol=1e-6)
        pts = ply_points(read_ply(out / "fused.ply"))
        assert summary["points"] == len(pts) > 0.5 * 5 * h * w
        clouds[mode] = np.abs(pts[:, 2] - 10.0 - 0.05 * pts[:, 0])
    # No resampling at the working resolution: the fused points sit on the plane to float precision;
    # the original-size maps are bilinear upsamplings of a (nearly linear) plane depth.
    assert clouds["working"].max() < 1e-4 and clouds["original"].max() < 1e-2
    # by default, maps written at the photos' size fuse at the working size: about the working run's points
    cfg = ReconstructConfig(preset="lite", max_size=64, num_views=3, cache_mb=16, fusion="normal")
    summary = reconstruct(scene, tmp_path / "default", cfg, quiet=True, model=plane_model())
    working = len(ply_points(read_ply(tmp_path / "working" / "fused.ply")))
    assert abs(summary["points"] - working) <= 0.1 * working
    pts = ply_points(read_ply(tmp_path / "default" / "fused.ply"))
    assert np.abs(pts[:, 2] - 10.0 - 0.05 * pts[:, 0]).max() < 1e-2
