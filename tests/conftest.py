"""Fixtures shared across test folders."""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest

# A shell starts a background job with Ctrl-C (SIGINT) ignored, and processes inherit that: the tests of what
# Ctrl-C does (in this process and in the commands they start) need it delivered, so the suite restores the
# default when it was started that way.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def make_synth_run(root: Path, seed: int = 3, num_views: int = 5, height: int = 96, width: int = 128,
                   fuse: bool = True, holes: bool = True) -> Path:
    """A ``reconstruct``-style output folder whose depth maps are the exact depths of a synthetic scene.

    With ``holes``, the farthest 10% of each view have no depth (0) and the confidence falls from 0.95
    at the left edge to 0.35 at the right; without, every pixel has its exact depth and confidence 0.9.
    ``scene/`` beside it holds the synthetic scene with ``gt_surface.ply``. Fused with the ``normal``
    filter when ``fuse``.
    """
    from mvsformerpp.io.pfm import read_pfm, write_pfm
    from mvsformerpp.synth import generate_scene

    scene = generate_scene(root / "scene", seed=seed, num_views=num_views, height=height, width=width)
    out = root / "out"
    (out / "depth_est").mkdir(parents=True)
    (out / "confidence").mkdir()
    shutil.copytree(scene / "images", out / "images")
    shutil.copytree(scene / "cams", out / "cams")
    shutil.copy(scene / "pair.txt", out / "pair.txt")
    names = {}
    for p in sorted((scene / "depth_gt").glob("*.pfm")):
        depth = read_pfm(p)
        conf = np.full(depth.shape, 0.9, np.float32)
        if holes:
            depth = np.where(depth > np.percentile(depth[depth > 0], 90), 0, depth).astype(np.float32)
            conf = np.broadcast_to(np.linspace(0.95, 0.35, depth.shape[1], dtype=np.float32), depth.shape)
        write_pfm(out / "depth_est" / p.name, depth)
        write_pfm(out / "confidence" / p.name, np.ascontiguousarray(conf))
        names[p.stem] = f"photo_{p.stem[-3:]}.png"
    (out / "views.json").write_text(json.dumps(names))
    (out / "config.json").write_text(json.dumps({
        "config": {"preset": "lite", "fusion": "normal", "num_views": 3, "device": "cpu", "precision": "fp32"},
        "resolved": {"long_side": width, "canvas": [width, height]}, "input": str(scene),
        "source_format": "mvsnet", "num_views_in_input": num_views}))
    points = None
    if fuse:
        from mvsformerpp.fusion import get_config
        from mvsformerpp.io.ply import ply_points, read_ply
        from mvsformerpp.pipelines.fuse import fuse as run_fuse

        # the normal preset's own threshold (0.5), not the one calibrated for the shipped weights that
        # config.json names: the tests below rely on its cut
        run_fuse(out, out / "fused.ply", get_config("normal"), quiet=True)
        points = len(ply_points(read_ply(out / "fused.ply")))
    (out / "summary.json").write_text(json.dumps({
        "views": num_views, "points": points, "timings": {"input_s": 0.1, "depth_s": 2.0, "fusion_s": 0.5,
                                                          "total_s": 2.6},
        "outputs": {"ply": str(out / "fused.ply") if fuse else None}}))
    return out


@pytest.fixture(scope="session")
def synth_run(tmp_path_factory) -> Path:
    """One exact-depth output folder per test session (read-only for the tests: copy it to change it)."""
    return make_synth_run(tmp_path_factory.mktemp("synth_run"))


@pytest.fixture
def synth_run_factory():
    """:func:`make_synth_run` for tests that need their own scene or settings."""
    return make_synth_run


@pytest.fixture(scope="session")
def exact_synth_run(tmp_path_factory) -> Path:
    """An output folder whose every pixel has its exact depth (no holes), fused; read-only for the tests."""
    return make_synth_run(tmp_path_factory.mktemp("exact_run"), seed=5, height=120, width=160, holes=False)


@pytest.fixture
def fake_network():
    """A new instance of the stand-in network of ``tests/inference/fake_model.py`` (exact plane depths)."""
    import importlib.util
    import sys

    name = "recon_fake_model"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).parent / "inference" / "fake_model.py")
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name].FakeMVSModel
