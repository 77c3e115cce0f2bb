"""``reconstruct`` from a folder of photos (SfM with pycolmap), from COLMAP, and with checkpoints."""

import dataclasses
import importlib.util
import json
import re
import shutil
import sys
from pathlib import Path

import pytest
import torch

from mvsformerpp.errors import FormatError, InputError, MissingDependencyError
from mvsformerpp.io.images import image_size
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.pipelines.demo import temple_dir
from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

FAST = ReconstructConfig(preset="lite", max_size=128, num_views=3, num_depth=32, cache_mb=64, max_images=3,
                         fusion="none")


def needs_network():
    import mvsformerpp

    if not hasattr(mvsformerpp, "build_model"):
        pytest.skip("the network (mvsformerpp.build_model) is not available in this checkout")


def fake_model():
    name = "recon_fake_model"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[1] / "inference" / "fake_model.py"
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name].FakeMVSModel()


def test_photo_folder_runs_sfm_once_and_reconstructs(photos, tmp_path, monkeypatch):
    pytest.importorskip("pycolmap")
    out = tmp_path / "out"
    summary = reconstruct(photos, out, FAST, quiet=True, model=fake_model())
    assert (out / "sfm" / "DONE").is_file() and (out / "sfm" / "dense" / "sparse").is_dir()
    assert summary["views"] == 3
    sfm_report = json.loads((out / "sfm" / "report.json").read_text())
    assert sfm_report["photos"] == 16 and sfm_report["registered"] + len(sfm_report["dropped"]) == 16
    assert sfm_report["points"] > 0 and 0 < sfm_report["mean_reprojection_error"] < 4
    page = (out / "report.html").read_text()
    assert f"<td>{sfm_report['registered']} of 16</td>" in page
    assert all(name in page for name in sfm_report["dropped"])
    # Undistortion changes each photo's size slightly; depth maps follow the (undistorted) photo.
    for i in range(3):
        depth = read_pfm(out / "depth_est" / f"{i:08d}.pfm")
        w, h = image_size(next((out / "images").glob(f"{i:08d}.*")))
        assert depth.shape == (h, w)
    # The second run reuses the SfM result: SfM must not run again.
    from mvsformerpp.pipelines import sfm

    monkeypatch.setattr(sfm, "import_pycolmap", lambda: pytest.fail("SfM ran again"))
    again = fake_model()
    resumed = reconstruct(photos, out, FAST, quiet=True, model=again)
    assert again.forwards == 0
    # ... and says so, with the time the SfM took when it ran
    assert summary["timings"]["sfm_reused"] is False and resumed["timings"]["sfm_reused"] is True
    assert sfm_report["seconds"] > 0
    import html

    page = html.unescape((out / "report.html").read_text())
    assert re.search(r"SfM [0-9.]+ (s|min) \(an earlier run's, reused\)", page)


def test_distorted_colmap_project_is_undistorted_first(photos, tmp_path):
    """A COLMAP project with SIMPLE_RADIAL cameras (SfM of the temple photos) goes through undistortion."""
    pytest.importorskip("pycolmap")
    from mvsformerpp.io.colmap import read_model
    from mvsformerpp.pipelines.sfm import run_sfm

    run_sfm(photos, tmp_path / "sfm", quiet=True)
    project = tmp_path / "project"
    shutil.copytree(tmp_path / "sfm" / "model", project / "sparse" / "0")
    shutil.copytree(photos, project / "images")
    assert {c.model for c in read_model(project / "sparse" / "0").cameras.values()} == {"SIMPLE_RADIAL"}
    out = tmp_path / "out"
    summary = reconstruct(project, out, FAST, quiet=True, model=fake_model())
    assert summary["views"] == 3
    assert {c.model for c in read_model(out / "undistorted" / "sparse").cameras.values()} == {"PINHOLE"}
    assert json.loads((out / "config.json").read_text())["source_format"] == "colmap"


def test_photo_folder_without_pycolmap_names_the_extra(photos, tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_pycolmap(name, *a, **kw):
        if name == "pycolmap":
            raise ImportError("No module named 'pycolmap'")
        return real_import(name, *a, **kw)

    monkeypatch.setattr(builtins, "__import__", no_pycolmap)
    with pytest.raises(MissingDependencyError, match=r"mvsformerpp\[colmap\]"):
        reconstruct(photos, tmp_path / "out", FAST, quiet=True)


def test_photo_folder_with_one_photo_is_refused(tmp_path):
    pytest.importorskip("pycolmap")
    d = tmp_path / "one"
    d.mkdir()
    shutil.copy(temple_dir() / "templeSR0001.png", d)
    with pytest.raises(InputError):
        reconstruct(d, tmp_path / "out", FAST, quiet=True)


def test_checkpoint_of_another_preset_is_refused(tmp_path):
    needs_network()

    ckpt = tmp_path / "wrong.pt"
    torch.save({"not_a_layer.weight": torch.zeros(3)}, ckpt)
    cfg = dataclasses.replace(FAST, checkpoint=str(ckpt))
    with pytest.raises((FormatError, InputError), match="wrong.pt"):
        reconstruct(temple_dir(), tmp_path / "out", cfg, quiet=True)
    with pytest.raises(InputError, match="not found"):
        reconstruct(temple_dir(), tmp_path / "out2", dataclasses.replace(FAST, checkpoint=str(tmp_path / "no.pt")),
                    quiet=True)
