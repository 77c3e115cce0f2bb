"""Fusion end to end on a synthetic scene with exact ground truth, clean and corrupted."""

import shutil

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.fusion import FusionConfig, fuse_depth_maps, get_config
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.images import read_image
from mvsformerpp.io.pfm import read_pfm, write_pfm
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply
from mvsformerpp.synth import generate_scene

METHODS = {
    "normal": FusionConfig(method="normal", num_consistent=2),
    "dynamic": FusionConfig(method="dynamic"),
    "gipuma": FusionConfig(method="gipuma", disp_threshold=0.25, num_consistent=2),
}


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    root = generate_scene(tmp_path_factory.mktemp("fusion") / "scene", seed=11, num_views=5, height=96, width=128)
    scene = load_scene(root)
    depths = [read_pfm(root / "depth_gt" / f"{i:08d}.pfm") for i in range(len(scene))]
    images = [read_image(v.image_path) for v in scene.views]
    gt = ply_points(read_ply(root / "gt_surface.ply"))
    span = max(v.depth_max for v in scene.views) - min(v.depth_min for v in scene.views)
    return root, scene, depths, images, gt, span


def _acc_comp(pred, gt):
    acc = cKDTree(gt).query(pred)[0]
    comp = cKDTree(pred).query(gt)[0]
    return acc, comp


@pytest.mark.parametrize("method", sorted(METHODS))
def test_ground_truth_depths_fuse_onto_the_surface(synth, method):
    root, scene, depths, images, gt, span = synth
    xyz, rgb = fuse_depth_maps(scene, depths, None, images, METHODS[method])
    assert len(xyz) > 0.5 * sum(d.size for d in depths) / (3 if method == "gipuma" else 1)
    acc, comp = _acc_comp(xyz, gt)
    assert np.median(acc) < 0.002 * span and np.mean(acc) < 0.01 * span
    assert np.median(comp) < 0.01 * span
    assert rgb.dtype == np.uint8 and rgb.shape == xyz.shape


@pytest.mark.parametrize("method", sorted(METHODS))
def test_filters_remove_noise_and_outliers(synth, method):
    root, scene, depths, images, gt, span = synth
    rng = np.random.default_rng(0)
    bad = []
    for d in depths:
        d = d.copy()
        out = rng.random(d.shape) < 0.2  # 20% wild outliers
        d[out] = rng.uniform(0.3, 3.0, out.sum()) * d[out]
        d *= 1 + rng.normal(0, 0.0005, d.shape)  # small noise everywhere
        bad.append(d.astype(np.float32))
    xyz, _ = fuse_depth_maps(scene, bad, None, images, METHODS[method])
    acc, _ = _acc_comp(xyz, gt)
    # Unfiltered, about 20% of the points would be wild; after the consistency check almost none are.
    assert np.mean(acc > 0.02 * span) < 0.01
    assert len(xyz) > 0.2 * sum(d.size for d in depths) / (3 if method == "gipuma" else 1)


def test_confidence_threshold_drops_pixels(synth):
    root, scene, depths, images, gt, span = synth
    confs = [np.where(np.arange(d.shape[1])[None] < d.shape[1] // 2, 0.9, 0.1).repeat(d.shape[0], 0)
             .astype(np.float32) for d in depths]
    full, _ = fuse_depth_maps(scene, depths, None, images, get_config("normal"))
    half, _ = fuse_depth_maps(scene, depths, confs, images, get_config("normal"))
    assert 0.2 * len(full) < len(half) < 0.6 * len(full)


@pytest.mark.parametrize("method", ["normal", "gipuma"])
def test_low_confidence_source_depths_are_not_used(synth, method):
    """A confident reference whose sources are all below the threshold has nothing to agree with."""
    root, scene, depths, images, gt, span = synth
    confs = [np.full(d.shape, 0.9 if i == 0 else 0.1, np.float32) for i, d in enumerate(depths)]
    cfg = METHODS[method]
    confident, _ = fuse_depth_maps(scene, depths, [np.full(d.shape, 0.9, np.float32) for d in depths], images, cfg)
    assert len(confident) > 0.1 * depths[0].size
    xyz, _ = fuse_depth_maps(scene, depths, confs, images, cfg)
    assert len(xyz) == 0


def test_fuse_command_on_a_scene_folder(synth, tmp_path):
    root, scene, depths, images, gt, span = synth
    folder = tmp_path / "run"
    shutil.copytree(root, folder)
    (folder / "depth_est").mkdir()
    (folder / "confidence").mkdir()
    for i, d in enumerate(depths):
        # Depth maps at half resolution: fusion scales the cameras to them.
        write_pfm(folder / "depth_est" / f"{i:08d}.pfm", d[::2, ::2])
        write_pfm(folder / "confidence" / f"{i:08d}.pfm", np.ones_like(d[::2, ::2]))
    out = tmp_path / "cloud.ply"
    assert main(["fuse", str(folder), "-o", str(out), "--fusion", "dynamic", "--quiet"]) == 0
    v = read_ply(out)
    pts = ply_points(v)
    assert ply_colors(v) is not None and len(pts) > 1000
    acc, _ = _acc_comp(pts, gt)
    assert np.median(acc) < 0.005 * span
    (folder / "depth_est" / "00000003.pfm").unlink()
    assert main(["fuse", str(folder), "-o", str(out), "--quiet"]) == 2  # a clear error, exit code 2
    with pytest.raises(InputError, match="no depth map"):
        from mvsformerpp.pipelines.fuse import fuse

        fuse(folder, out, quiet=True)
