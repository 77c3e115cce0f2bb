import json
import shutil

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.io.colmap_model import write_model
from mvsformerpp.io.detect import detect_layout, load_scene
from mvsformerpp.io.mvsnet import write_pair

from .colmap_synth import synthetic_model, write_photos
from .fakes import DTU_PAIR, TEMPLE, make_dtu, make_dtu_mvsnet


def test_detects_every_layout(tmp_path):
    mv = make_dtu_mvsnet(tmp_path / "mvs")
    assert detect_layout(mv) == "mvsnet" and detect_layout(mv / "pair.txt") == "mvsnet"
    dtu = make_dtu(tmp_path / "dtu")
    assert detect_layout(dtu) == "dtu"
    assert detect_layout(TEMPLE) == "middlebury" and detect_layout(TEMPLE / "templeSR_par.txt") == "middlebury"
    model = synthetic_model(n_views=3)
    for sub in ("sparse/0", "sparse", "."):
        proj = tmp_path / f"colmap_{sub.replace('/', '_')}"
        write_model(model, proj / sub, ".txt")
        write_photos(model, proj / "images")
        assert detect_layout(proj) == "colmap"
        assert len(load_scene(proj)) == 3
    assert detect_layout(tmp_path / "colmap_sparse_0" / "sparse" / "0" / "cameras.txt") == "colmap"
    tnt = tmp_path / "intermediate" / "Horse"
    shutil.copytree(mv, tnt)
    (tmp_path / "intermediate" / "short_range_cameras").mkdir()
    assert detect_layout(tnt) == "tnt"
    bl = tmp_path / "bl"
    shutil.copytree(mv / "images", bl / "blended_images")
    shutil.copytree(mv / "cams", bl / "cams")
    assert detect_layout(bl) == "blendedmvs"


def test_photos_without_cameras(tmp_path):
    Image.new("RGB", (8, 8)).save(tmp_path / "a.jpg")
    assert detect_layout(tmp_path) == "images"
    with pytest.raises(InputError, match="no cameras; multi-view stereo needs calibrated cameras"):
        load_scene(tmp_path)
    # Photos in images/ count too; a folder with cams/ but no images/ is not an MVSNet scene.
    (tmp_path / "p" / "images").mkdir(parents=True)
    shutil.copy(tmp_path / "a.jpg", tmp_path / "p" / "images" / "a.jpg")
    assert detect_layout(tmp_path / "p") == "images"


def test_nothing_there(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no scene found here; looked for an MVSNet folder .* Middlebury"):
        detect_layout(tmp_path / "empty")
    with pytest.raises(InputError, match="no such file"):
        detect_layout(tmp_path / "missing")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="cannot tell the scene layout"):
        load_scene(tmp_path / "notes.txt")


def test_overrides(tmp_path):
    mv = make_dtu_mvsnet(tmp_path / "mvs")
    # A broken depth line is ignored when the depth range is given.
    cam = (mv / "cams" / "00000001_cam.txt").read_text().replace("425.0 2.5", "425.0 nan")
    (mv / "cams" / "00000001_cam.txt").write_text(cam)
    with pytest.raises(InputError, match="non-finite"):
        load_scene(mv)
    scene = load_scene(mv, depth_range=(400, 900))
    assert all((v.depth_min, v.depth_max) == (400, 900) for v in scene.views)
    with pytest.raises(InputError, match="0 < min < max"):
        load_scene(mv, depth_range=(900, 400))
    # Forced depth format: "425 2.5" read as min + max is not a valid range.
    shutil.copy(DTU_PAIR / "00000001_cam.txt", mv / "cams" / "00000001_cam.txt")
    with pytest.raises(InputError, match="0 < min < max"):
        load_scene(mv, depth_format="max")
    assert load_scene(mv, num_neighbors=0).views[0].neighbors == []
    temple = load_scene(TEMPLE, num_neighbors=4)
    assert all(len(v.neighbors) == 4 for v in temple.views)
    assert max(len(v.neighbors) for v in load_scene(TEMPLE).views) > 4
    # A DTU root with several scans needs the scan.
    dtu = make_dtu(tmp_path / "dtu", scans=("scan1", "scan4"))
    with pytest.raises(InputError, match="choose one"):
        load_scene(dtu)
    assert load_scene(dtu, scan="scan4").source_format == "dtu"
    write_pair(mv / "pair.txt", {0: [(1, 1.0)], 1: [(9, 1.0)]})
    with pytest.raises(InputError, match=r"\[9\]"):
        load_scene(mv)


def test_info_command_text_and_json(tmp_path, capsys):
    assert main(["info", str(TEMPLE)]) == 0
    out = capsys.readouterr().out
    assert "layout:       middlebury" in out and "views:        16" in out and "640x480 (16 views)" in out
    assert main(["info", str(TEMPLE), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["num_views"] == 16 and data["resolutions"] == {"640x480": 16}
    scene = load_scene(TEMPLE)
    mins = [v.depth_min for v in scene.views]
    assert data["depth_min"] == {"min": min(mins), "median": float(np.median(mins)), "max": max(mins)}
    counts = [len(v.neighbors) for v in scene.views]
    assert data["neighbors"] == {"min": min(counts), "median": float(np.median(counts)), "max": max(counts)}
    dtu = make_dtu(tmp_path / "dtu")
    assert main(["info", str(dtu), "--json", "--num-neighbors", "1"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["layout"] == "dtu" and data["views_with_gt_depth"] == 2 and data["neighbors"]["max"] == 1
    assert main(["info", str(dtu), "--depth-range", "1", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["depth_max"]["median"] == 2.0
    assert main(["info", str(dtu), "--views"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-2].split()[:3] == ["0", "00000000", "640x512"] and lines[-2].split()[-1] == "1"
    assert main(["info", str(dtu), "--views", "--json"]) == 0
    views = json.loads(capsys.readouterr().out)["views"]
    assert views[1]["neighbors"] == [0] and views[1]["depth_gt"].endswith("depth_map_0001.pfm")


def test_info_says_what_stage1_resolves_and_which_ranges_reconstruct_widens(capsys):
    """``info`` prints stage 1's image shift per depth plane at reconstruct's working size; it is linear in
    the inverse-depth step (the same middle, a 58x narrower range: 58x less shift), and views below
    ``--min-parallax``'s default are named as the ones reconstruct widens."""
    def parallax(lo, hi):
        assert main(["info", str(TEMPLE), "--depth-range", str(lo), str(hi), "--json"]) == 0
        return json.loads(capsys.readouterr().out)["stage1_parallax"]

    wide, tight = parallax(0.5, 0.65), parallax(0.56, 0.5625)
    assert wide["long_side"] == 640 and wide["views"] == 16 and wide["widened_views"] == []
    ratio = (1 / 0.5 - 1 / 0.65) / (1 / 0.56 - 1 / 0.5625)
    assert wide["shift"]["median"] / tight["shift"]["median"] == pytest.approx(ratio, rel=0.05)
    assert tight["widened_views"] == list(range(16)) and tight["min_parallax"] == 0.15
    assert main(["info", str(TEMPLE), "--depth-range", "0.56", "0.5625"]) == 0
    out = capsys.readouterr().out
    assert "px of image shift per depth plane" in out and "16 views below 0.15 px" in out
    assert main(["info", str(TEMPLE), "--depth-range", "0.56", "0.5625", "--preset", "paper", "--json"]) == 0
    paper = json.loads(capsys.readouterr().out)["stage1_parallax"]  # the paper preset widens nothing by default
    assert paper["min_parallax"] == 0 and paper["widened_views"] == [] and paper["shift"]["median"] > 0


def test_info_command_errors(tmp_path, capsys):
    Image.new("RGB", (8, 8)).save(tmp_path / "a.png")
    assert main(["info", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "cameras" in err and "Traceback" not in err
    assert main(["info", str(tmp_path / "nope")]) == 2
    assert "no such file" in capsys.readouterr().err
