"""The HTML report: content from the output folder, self-contained, rendered by a real browser."""

import json
import re
import shutil

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.io.output_folder import open_run
from mvsformerpp.utils.colormap import turbo
from mvsformerpp.viewer.report import collect, hatch, map_thumbnail, summary_lines, write_report


def test_invalid_pixels_are_distinct_from_every_colour_of_the_scale():
    depth = np.full((40, 50), 2.0, np.float32)
    depth[:, :10] = 1.0  # the nearest valid depth: the scale's first colour
    depth[:, 40:] = 0.0  # no depth
    rgb = map_thumbnail(depth, 1.0, 3.0, depth > 0)
    scale = turbo(np.linspace(0, 1, 1001)).astype(int)
    invalid = rgb[:, 40:].reshape(-1, 3).astype(int)
    # every invalid pixel is far from every colour of the scale (grey stripes vs a saturated map)
    dist = np.abs(invalid[:, None, :] - scale[None]).sum(-1).min(1)
    assert dist.min() > 60
    assert (rgb[:, :10] == turbo(np.zeros(1))[0]).all()
    assert len({tuple(c) for c in hatch((12, 12)).reshape(-1, 3)}) == 2


def test_report_of_a_synthetic_run(synth_run, tmp_path, screenshot):
    out = tmp_path / "out"
    shutil.copytree(synth_run, out)
    sfm = out / "sfm"
    sfm.mkdir()
    (sfm / "report.json").write_text(json.dumps({
        "registered": 5, "photos": 6, "dropped": ["blurry_0007.jpg"], "points": 1234, "observations": 5000,
        "mean_track_length": 4.05, "mean_reprojection_error": 0.61,
        "cameras": [{"id": 1, "model": "SIMPLE_RADIAL", "width": 128, "height": 96,
                     "params": {"f": 110.0, "cx": 64.0, "cy": 48.0, "k": 0.01}}]}))
    path = write_report(out)
    text = path.read_text()
    # self-contained: nothing fetched from elsewhere, every image inlined; thumbnails link to the folder's
    # full-size files by relative paths
    assert not re.search(r"""src\s*=\s*["'](?!data:)""", text)
    assert "http://" not in text and "https://" not in text
    assert text.count("data:image/") == 3 * 5  # photo, depth, confidence per view
    hrefs = re.findall(r'href="([^"]+)"', text)
    assert len(hrefs) >= 5 and all(not h.startswith("/") and (out / h).is_file() for h in hrefs)
    facts = collect(open_run(out))
    points = facts["points"]
    assert points > 1000
    for needle in (f"{points:,}", "blurry_0007.jpg", "5 of 6", "0.610 px", "SIMPLE_RADIAL", "photo_003.png",
                   "long side 128 px", "scene units", "90% of pixels with depth"):
        assert needle in text, needle
    lines = summary_lines(facts)
    assert len(lines) <= 8
    assert any("registered 5 of 6 photos" in ln for ln in lines)
    assert any(f"{points:,} points" in ln for ln in lines)

    png = screenshot(path.as_uri(), tmp_path / "report.png")
    shot = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert shot.shape[0] >= 1000 and shot.std() > 20  # not a blank page
    # the depth thumbnails are there: many saturated (colour-mapped) pixels, and the grey hatching
    saturated = (shot.max(-1) - shot.min(-1)) > 120
    assert saturated.mean() > 0.02
    grey = np.all(shot == [150, 150, 150], -1) | np.all(shot == [215, 215, 215], -1)
    assert grey.sum() > 5000  # hatched no-depth pixels, far more than the legend swatches


def test_report_command_and_bad_folder(synth_run, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(synth_run, out)
    assert main(["report", str(out), "-o", str(tmp_path / "r.html")]) == 0
    assert (tmp_path / "r.html").is_file() and not (out / "report.html").exists()
    printed = capsys.readouterr().out
    assert "fused cloud" in printed and "r.html" in printed
    with pytest.raises(InputError, match="reconstruct INPUT -o OUT"):
        write_report(tmp_path / "empty")
    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty")]) == 2
    assert "mvsformerpp reconstruct" in capsys.readouterr().err


def test_reconstruct_writes_the_report_and_prints_the_summary(tmp_path, capsys, fake_network):
    import dataclasses

    from mvsformerpp.cli.reconstruct import print_summary
    from mvsformerpp.pipelines.demo import temple_dir
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

    cfg = ReconstructConfig(preset="lite", max_size=128, num_views=3, num_depth=32, cache_mb=64, max_images=3,
                            fusion="none")
    out = tmp_path / "out"
    summary = reconstruct(temple_dir(), out, cfg, quiet=True, model=fake_network())
    text = (out / "report.html").read_text()
    assert "templeSR0001" in text and text.count("data:image/") == 9
    assert "none (fusion off)" in text
    print_summary(summary, out)
    printed = capsys.readouterr().out
    assert "3 of 16 views" in printed and "long side 128 px" in printed and "report.html" in printed
    assert len(printed.splitlines()) <= 10
    cfg = dataclasses.replace(cfg, fusion="normal")
    summary = reconstruct(temple_dir(), out, cfg, quiet=True, model=fake_network())
    assert f"{summary['points']:,}" in (out / "report.html").read_text()


def test_the_report_names_the_weights_that_ran(synth_run, tmp_path, fake_network):
    from mvsformerpp.models.shipped import shipped_record
    from mvsformerpp.models.weights import weights_for

    def weights_name(preset, checkpoint=None):
        return weights_for(preset, checkpoint).name

    record = shipped_record()
    assert weights_name("lite").startswith(f"the shipped default weights {record['file']}")
    assert record["sha256"][:12] in weights_name("lite")
    assert weights_name("lite", "w.safetensors") == "w.safetensors"
    assert weights_name("paper").startswith("random initialisation")

    out = tmp_path / "out"
    shutil.copytree(synth_run, out)
    config = json.loads((out / "config.json").read_text())
    config["config"].update(preset="lite", checkpoint=None)
    config["resolved"]["weights"] = weights_name("lite")
    (out / "config.json").write_text(json.dumps(config))
    text = write_report(out).read_text()
    assert f"shipped default weights {record['file']}" in text and "random weights" not in text
    # a folder written before config.json named the weights: told from the preset and the checkpoint
    del config["resolved"]["weights"]
    (out / "config.json").write_text(json.dumps(config))
    assert "lite (the shipped default weights)" in write_report(out).read_text()
    config["config"].update(preset="paper")
    (out / "config.json").write_text(json.dumps(config))
    assert "paper (random initialisation)" in write_report(out).read_text()


def test_depth_previews_show_what_fusion_keeps(synth_run, tmp_path):
    """Pixels below the fusion threshold are grey (not a colour of the scale) and the scale follows the kept
    pixels; the report says so, and a report written elsewhere links back to the folder's files."""
    from mvsformerpp.utils.colormap import depth_colors

    depth = np.full((10, 20), 2.0, np.float32)
    depth[:, 10:] = np.linspace(1.0, 3.0, 10)[None]  # kept: 1 .. 3
    depth[:, :3] = 100.0  # far background that fusion drops
    depth[0, :] = 0.0
    conf = np.where(depth > 50, 0.1, 0.9).astype(np.float32)
    rgb = depth_colors(depth, conf, 0.5).astype(int)
    dropped = rgb[1:, :3]
    assert (dropped[..., 0] == dropped[..., 1]).all() and (dropped[..., 1] == dropped[..., 2]).all()
    assert (rgb[0] == 0).all()  # no depth: black
    assert (rgb[1:, 10] == turbo(np.zeros(1))[0]).all()  # the kept range spans the whole scale
    assert np.abs(rgb[1:, 19] - turbo(np.ones(1))[0]).max() <= 40
    # the report of a run whose confidence falls below the threshold towards the right
    (tmp_path / "elsewhere").mkdir()
    path = write_report(synth_run, tmp_path / "elsewhere" / "r.html")
    text = path.read_text()
    assert "below the fusion threshold" in text and "Click a thumbnail" in text
    for href in re.findall(r'href="([^"]+)"', text):
        assert (path.parent / href).resolve().is_file()


def test_a_run_again_says_what_it_reused(tmp_path, capsys, fake_network):
    """The summary of a resumed run names the views and the fusion it reused instead of computing."""
    from mvsformerpp.cli.reconstruct import print_summary
    from mvsformerpp.pipelines.demo import temple_dir
    from mvsformerpp.pipelines.reconstruct import ReconstructConfig, reconstruct

    cfg = ReconstructConfig(preset="lite", max_size=128, num_views=3, num_depth=32, cache_mb=64, max_images=3)
    out = tmp_path / "out"
    first = reconstruct(temple_dir(), out, cfg, quiet=True, model=fake_network())
    assert first["timings"]["views_reused"] == 0 and first["timings"]["fusion_reused"] is False
    again = reconstruct(temple_dir(), out, cfg, quiet=True, model=fake_network())
    assert again["timings"]["views_reused"] == 3 and again["timings"]["fusion_reused"] is True
    print_summary(again, out)
    printed = capsys.readouterr().out
    assert "(0 views computed, 3 reused)" in printed and "fusion reused" in printed
    assert "3 reused" in (out / "report.html").read_text()


def test_a_folder_name_that_is_not_utf8_is_reported(synth_run, tmp_path):
    """Linux allows any bytes in a name; the report (and every text file, and what is printed) keeps them
    instead of crashing."""
    import os
    import subprocess
    import sys

    out = tmp_path / os.fsdecode(b"run\xff")
    shutil.copytree(synth_run, out)
    run = subprocess.run([sys.executable, "-m", "mvsformerpp", "report", os.fsencode(str(out))], capture_output=True,
                         env={**os.environ, "LC_ALL": "C.UTF-8", "PYTHONIOENCODING": "utf-8"})
    assert run.returncode == 0, run.stderr.decode(errors="replace")
    assert os.fsencode(str(out / "report.html")) in run.stdout
    assert os.fsencode(str(out)) in (out / "report.html").read_bytes()
