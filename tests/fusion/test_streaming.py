"""Streaming fusion: the same points as the in-memory fusion, memory bounded independently of the view count."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.fusion import PRESETS, fuse_depth_maps, get_config
from mvsformerpp.fusion.store import VIEW_BYTES_PER_PIXEL
from mvsformerpp.io.depth_folder import load_depth_folder
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply
from mvsformerpp.pipelines.fuse import fuse_streaming, minimum_memory_bytes, view_cache_bytes
from mvsformerpp.synth import generate_scene
from mvsformerpp.synth.strip import generate_strip_scene


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A rendered scene of 7 views with noisy depth maps and varied confidences in depth_est/."""
    from mvsformerpp.io.pfm import read_pfm, write_pfm

    root = generate_scene(tmp_path_factory.mktemp("stream") / "scene", seed=5, num_views=7, height=48, width=64)
    rng = np.random.default_rng(0)
    for i in range(7):
        d = read_pfm(root / "depth_gt" / f"{i:08d}.pfm")
        out = rng.random(d.shape) < 0.1
        d = np.where(out, d * rng.uniform(0.5, 2.0, d.shape), d * (1 + rng.normal(0, 0.001, d.shape)))
        write_pfm(root / "depth_est" / f"{i:08d}.pfm", d.astype(np.float32))
        y, x = np.mgrid[: d.shape[0], : d.shape[1]]  # smooth, as a network's confidence is
        conf = 0.55 + 0.45 * np.sin(x / 7.0 + i) * np.cos(y / 11.0 - i)
        write_pfm(root / "confidence" / f"{i:08d}.pfm", conf.astype(np.float32))
    return root


CONFIGS = {**{f"preset-{k}": v for k, v in PRESETS.items()},
           "gipuma-2src": get_config("gipuma", num_src_views=2, num_consistent=1),
           "normal-3src": get_config("normal", num_src_views=3, num_consistent=2)}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_streaming_equals_in_memory_fusion(folder, tmp_path, name):
    cfg = CONFIGS[name]
    scene, depths, confs, images = load_depth_folder(folder)
    xyz, rgb = fuse_depth_maps(scene, depths, confs, images, cfg)
    # The smallest budget fusion accepts: the cache holds one reference and its sources, nothing more.
    S = min(cfg.num_src_views, 6)
    need = minimum_memory_bytes(48 * 64, S, cfg)
    res = fuse_streaming(folder, tmp_path / "s.ply", cfg, quiet=True, memory_gb=need / 2**30)
    v = read_ply(res["ply"])
    assert len(xyz) > 500 and res["points"] == len(xyz)
    np.testing.assert_array_equal(ply_points(v), xyz.astype(np.float64))
    np.testing.assert_array_equal(ply_colors(v), rgb)
    if S < 6:  # views were evicted and read again: the store really streamed
        assert res["view_cache"]["misses"] > len(scene) and res["view_cache"]["evictions"] > 0


def test_a_budget_below_one_working_set_is_refused(folder, tmp_path):
    with pytest.raises(InputError, match="too small for fusion.*10 source views"):
        view_cache_bytes(1000 * 1000, 10, get_config("normal"), 0.05 * 2**30)
    assert main(["fuse", str(folder), "-o", str(tmp_path / "x.ply"), "--memory-gb", "0.0001", "--quiet"]) == 2
    assert not (tmp_path / "x.ply").exists()


def _peak_rss_mb(folder, out, memory_gb: float) -> float:
    code = ("import resource, sys; from mvsformerpp.cli import main; "
            "from mvsformerpp.utils.allocator import tune_allocator; tune_allocator(); "
            f"rc = main(['fuse', {str(folder)!r}, '-o', {str(out)!r}, '--num-src-views', '2', "
            f"'--memory-gb', '{memory_gb}', '--quiet']); "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024); sys.exit(rc)")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}  # (a loaded 2-core machine: no thread contention)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    return float(done.stdout.split()[-1])


def test_four_times_the_views_do_not_raise_peak_memory(tmp_path):
    h, w, n = 240, 320, 6
    small = generate_strip_scene(tmp_path / "small", num_views=n, height=h, width=w)
    large = generate_strip_scene(tmp_path / "large", num_views=4 * n, height=h, width=w)
    # A budget of one reference with its 2 sources plus 2 views: both scenes stream through the cache.
    budget = (minimum_memory_bytes(h * w, 2, get_config("normal")) + 2 * VIEW_BYTES_PER_PIXEL * h * w) / 2**30
    rss_small = _peak_rss_mb(small, tmp_path / "small.ply", budget)
    rss_large = _peak_rss_mb(large, tmp_path / "large.ply", budget)
    extra_views_mb = 3 * n * VIEW_BYTES_PER_PIXEL * h * w / 2**20  # what in-memory fusion would add
    print(json.dumps({"rss_small_mb": rss_small, "rss_large_mb": rss_large, "extra_views_mb": extra_views_mb}))
    assert rss_large < 1.5 * rss_small
    assert rss_large - rss_small < 0.5 * extra_views_mb
    assert len(ply_points(read_ply(tmp_path / "large.ply"))) > 3 * len(ply_points(read_ply(tmp_path / "small.ply")))
