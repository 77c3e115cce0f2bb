"""Depth lines, depth ranges, empty clouds, SfM folders fed back, fuse killed mid-write."""

import logging
import shlex
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from mvsformerpp.cli import main
from mvsformerpp.io.mvsnet import read_cam
from mvsformerpp.io.pfm import read_pfm, write_pfm
from mvsformerpp.pipelines.reconstruct import reconstruct

sys.path.insert(0, str(Path(__file__).parent))
from test_reconstruct import FAST, fake_model  # noqa: E402


def synth(path, views=3):
    from mvsformerpp.synth import generate_scene

    return generate_scene(path, seed=2, num_views=views, height=64, width=96, gt_points=500)


def set_depth_lines(scene: Path, line: str) -> None:
    for p in (scene / "cams").glob("*_cam.txt"):
        lines = p.read_text().strip().splitlines()
        lines[-1] = line
        p.write_text("\n".join(lines) + "\n")


def with_depths(scene: Path, confidence: float) -> Path:
    """The scene's ground-truth depth maps as depth_est/, with a constant confidence."""
    for p in sorted((scene / "depth_gt").glob("*.pfm")):
        d = read_pfm(p)
        write_pfm(scene / "depth_est" / p.name, d)
        write_pfm(scene / "confidence" / p.name, np.full_like(d, confidence))
    return scene


@pytest.mark.parametrize("line, fmt, form", [("2 3", "auto", "MIN MAX"), ("2 0.01", "auto", "MIN INTERVAL"),
                                             ("2 3", "interval", "MIN INTERVAL")])
def test_info_says_how_two_number_depth_lines_were_read(tmp_path, capsys, line, fmt, form):
    s = synth(tmp_path / "s")
    set_depth_lines(s, line)
    assert main(["info", str(s), "--depth-format", fmt]) == 0
    assert f"depth lines:  3 read as {form}" in capsys.readouterr().out


def test_reconstruct_depth_format_and_depth_range_override(tmp_path):
    s = synth(tmp_path / "s")
    set_depth_lines(s, "2 3")
    cfg = FAST.__class__(**{**FAST.__dict__, "depth_format": "interval"})
    reconstruct(s, tmp_path / "o1", cfg, quiet=True, model=fake_model())
    cam = read_cam(tmp_path / "o1" / "cams" / "00000000_cam.txt")
    assert cam.depth_min == 2 and cam.depth_max == pytest.approx(2 + 3 * 191)
    # Depth lines that are wrong do not matter when --depth-range replaces them (as for info).
    set_depth_lines(s, "5 0")
    cfg = FAST.__class__(**{**FAST.__dict__, "depth_range": (1.0, 9.0)})
    reconstruct(s, tmp_path / "o2", cfg, quiet=True, model=fake_model())
    assert read_cam(tmp_path / "o2" / "cams" / "00000001_cam.txt").depth_max == 9.0


def test_a_depth_range_that_misses_the_scene_is_warned_about(tmp_path, caplog):
    s = synth(tmp_path / "s")
    own = read_cam(s / "cams" / "00000000_cam.txt")
    with caplog.at_level(logging.WARNING, logger="mvsformerpp"):
        cfg = FAST.__class__(**{**FAST.__dict__, "depth_range": (own.depth_min / 100, own.depth_max / 100)})
        reconstruct(s, tmp_path / "o1", cfg, quiet=True, model=fake_model())
    assert "covers less than half of the depth range the input gives 3 of 3 views" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="mvsformerpp"):
        cfg = FAST.__class__(**{**FAST.__dict__, "depth_range": (own.depth_min * 0.9, own.depth_max * 1.1)})
        reconstruct(s, tmp_path / "o2", cfg, quiet=True, model=fake_model())
    assert "covers less than half" not in caplog.text


def test_empty_cloud_message_gives_percentiles_and_a_command_that_works_as_printed(tmp_path, capsys):
    s = with_depths(synth(tmp_path / "my scene"), confidence=0.3)  # below the default --conf 0.5
    out = tmp_path / "out dir" / "cloud.ply"
    out.parent.mkdir()
    assert main(["fuse", str(s), "-o", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("warning: fusion (normal, --conf 0.5) kept no point")
    assert "median 0.300" in err
    command = err.split("These settings keep ")[1].split(": ", 1)[1]
    argv = shlex.split(command)
    assert argv[:2] == ["mvsformerpp", "fuse"] and argv[2] == str(s) and "--conf" in argv
    assert main(argv[1:]) == 0
    from mvsformerpp.io.ply import ply_points, read_ply

    kept = int(err.split("These settings keep ")[1].split(" points")[0].replace(",", ""))
    assert len(ply_points(read_ply(out))) == kept > 0


def test_sfm_output_folder_pairs_the_undistorted_model_with_its_photos(tmp_path):
    sys.path.insert(0, str(Path(__file__).parents[1] / "io"))
    from colmap_synth import synthetic_model, write_photos

    from mvsformerpp.io.colmap import find_colmap_model
    from mvsformerpp.io.colmap_model import write_model

    sfm = tmp_path / "sfm"
    distorted = synthetic_model(n_views=3, width=65, height=49, model="SIMPLE_RADIAL", params=[60, 32.5, 24.5, 0.01])
    write_model(distorted, sfm / "sparse" / "0", ext=".txt")
    write_model(distorted, sfm / "model", ext=".txt")
    undistorted = synthetic_model(n_views=3, width=64, height=48)
    write_model(undistorted, sfm / "dense" / "sparse", ext=".txt")
    write_photos(undistorted, sfm / "dense" / "images")
    model_dir, image_dir = find_colmap_model(sfm)
    assert (model_dir, image_dir) == (sfm / "dense" / "sparse", sfm / "dense" / "images")
    from mvsformerpp.io.detect import load_scene

    scene = load_scene(sfm)
    assert [v.width for v in scene.views] == [64] * 3 and scene.views[0].image_path.parent == sfm / "dense" / "images"


HANG_ON_FSYNC = textwrap.dedent("""
    import os, sys, time
    signal = sys.argv.pop(1)
    def hang(fd):
        open(signal, "w").close()
        time.sleep(600)
    os.fsync = hang
    from mvsformerpp.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def test_kill_9_during_fuse_then_rerun_matches_an_uninterrupted_run(tmp_path):
    s = with_depths(synth(tmp_path / "s", views=4), confidence=0.9)
    full = tmp_path / "full.ply"
    assert main(["fuse", str(s), "-o", str(full), "--quiet"]) == 0
    signal = tmp_path / "writing"
    proc = subprocess.Popen([sys.executable, "-c", HANG_ON_FSYNC, str(signal), "fuse", str(s), "--quiet"])
    deadline = time.monotonic() + 120
    while not signal.exists():
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    assert not (s / "fused.ply").exists() and list(s.glob(".fused.ply.*.tmp"))  # killed mid-write
    assert main(["fuse", str(s), "--quiet"]) == 0
    assert (s / "fused.ply").read_bytes() == full.read_bytes()
    assert not list(s.glob(".fused.ply.*.tmp"))


def test_a_depth_range_that_misses_the_sparse_points_is_warned_about(tmp_path, caplog):
    sys.path.insert(0, str(Path(__file__).parents[1] / "io"))
    from colmap_synth import synthetic_model, write_photos

    from mvsformerpp.io.colmap_model import write_model

    model = synthetic_model(n_views=3, n_points=400)  # cameras 4 units from the points
    project = tmp_path / "colmap"
    write_model(model, project / "sparse" / "0", ext=".txt")
    write_photos(model, project / "images")
    for k, (rng, warned) in enumerate([((0.1, 1.0), True), ((1.0, 10.0), False)]):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="mvsformerpp"):
            cfg = FAST.__class__(**{**FAST.__dict__, "depth_range": rng})
            reconstruct(project, tmp_path / f"o{k}", cfg, quiet=True, model=fake_model())
        assert ("leaves out most of the sparse points seen by 3 of 3 views" in caplog.text) == warned


def test_all_black_masks_are_named_as_the_reason_for_an_empty_cloud(tmp_path, capsys):
    """fuse with masks that mark nothing blames the masks, not the cameras or the depth ranges."""
    from PIL import Image

    s = with_depths(synth(tmp_path / "s"), confidence=0.9)
    (tmp_path / "masks").mkdir()
    for p in sorted((s / "images").iterdir()):
        with Image.open(p) as im:
            Image.new("L", im.size, 0).save(tmp_path / "masks" / f"{p.stem}.png")
    assert main(["fuse", str(s), "-o", str(tmp_path / "c.ply"), "--mask-dir", str(tmp_path / "masks"),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "the masks mark no pixel of any view as object" in err and "check the cameras" not in err


@pytest.mark.parametrize("name", ["plain", "with space", "new\nline", "tab\tand\\back", "quo'te", "bad\udcff byte"])
def test_printed_commands_name_every_file_exactly_on_one_line(tmp_path, name):
    """The advice's command line survives a shell, whatever the folder is called (newlines, quotes, bad bytes)."""
    import os
    import subprocess

    from mvsformerpp.pipelines.empty_cloud import shell_quote

    quoted = shell_quote(name)
    assert "\n" not in quoted
    out = subprocess.run(["sh", "-c", f"printf %s {quoted}"], capture_output=True, check=True).stdout
    assert out == os.fsencode(name)
