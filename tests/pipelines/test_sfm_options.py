"""SfM options on real photos (the temple), failures explained, and OUT/sfm fed back in."""

import json

import pytest

from mvsformerpp.errors import InputError
from mvsformerpp.pipelines.scene_input import load_input
from mvsformerpp.pipelines.sfm import SfMConfig, run_sfm


def test_single_pinhole_camera_and_sequential_matching(photos, tmp_path, capsys):
    pytest.importorskip("pycolmap")
    config = SfMConfig(camera_model="PINHOLE", single_camera=True, matcher="sequential")
    dense = run_sfm(photos, tmp_path / "sfm", quiet=False, config=config)
    err = capsys.readouterr().err
    assert "SfM: features" in err and "16/16" in err  # per-photo progress
    report = json.loads((tmp_path / "sfm" / "report.json").read_text())
    assert report["registered"] >= 3 and report["photos"] == 16
    assert [c["model"] for c in report["cameras"]] == ["PINHOLE"]  # one camera for all photos
    assert json.loads((tmp_path / "sfm" / "options.json").read_text())["matcher"] == "sequential"
    # the SfM folder itself is accepted as an input: its undistorted project is used
    scene = load_input(tmp_path / "sfm", tmp_path / "out", quiet=True)
    assert len(scene) == report["registered"] and (dense / "sparse").is_dir()


def test_pycolmap_failures_are_explained(photos, tmp_path, monkeypatch):
    pycolmap = pytest.importorskip("pycolmap")

    def broken(*args, **kwargs):
        raise RuntimeError("Check failed: something inside COLMAP")

    monkeypatch.setattr(pycolmap, "incremental_mapping", broken)
    with pytest.raises(InputError, match=r"failed while mapping \(Check failed: something inside COLMAP\); take"):
        run_sfm(photos, tmp_path / "sfm", quiet=True, config=SfMConfig(max_image_size=320))


def test_bad_sfm_settings():
    with pytest.raises(InputError, match="not a COLMAP camera model"):
        SfMConfig(camera_model="FISHEYE_PRO")
    with pytest.raises(InputError, match="--sfm-max-size"):
        SfMConfig(max_image_size=10)


def test_exhaustive_matching_and_mapping_show_their_real_progress(photos, tmp_path, capsys):
    """Every pair is matched with a progress bar that reaches all 120 pairs of 16 photos, and the registered
    bar ends at the number of photos the model holds (the first pair included)."""
    pytest.importorskip("pycolmap")
    run_sfm(photos, tmp_path / "sfm", quiet=False, config=SfMConfig(max_image_size=320))
    err = capsys.readouterr().err
    report = json.loads((tmp_path / "sfm" / "report.json").read_text())
    assert "SfM: matching" in err and "120/120" in err
    assert f"{report['registered']}/16" in err.split("SfM: registered")[-1]
    assert not (tmp_path / "sfm" / "pairs.txt").exists()
