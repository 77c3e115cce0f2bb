import errno
import json

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import InputError
from mvsformerpp.io import output_folder as of
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.utils.colormap import colorize, turbo


def tiny_scene(shift=0.0):
    v = [View(name=f"v{i}", image_path=f"v{i}.png", width=8, height=6, K=np.eye(3), R=np.eye(3),
              t=[i + shift, 0, 0]) for i in range(2)]
    return Scene(v)


def test_turbo_endpoints_and_monotone_hue():
    out = turbo(np.array([0.15, 0.5, 0.9, -1.0, 2.0]))
    assert out.shape == (5, 3) and out.dtype == np.uint8
    rgb = out.astype(int)
    assert rgb[0, 2] > rgb[0, 0] + 100  # blue end
    assert rgb[2, 0] > rgb[2, 2] + 100  # red end
    assert rgb[1, 1] > 200  # green-yellow middle
    assert (rgb[3] == turbo(np.array([0.0]))[0]).all() and (rgb[4] == turbo(np.array([1.0]))[0]).all()  # clipped


def test_colorize_blacks_out_invalid_pixels():
    d = np.array([[0.0, 1.0], [2.0, np.nan]])
    out = colorize(d, invalid=d <= 0)
    assert (out[0, 0] == 0).all() and (out[1, 1] == 0).all() and out[0, 1].any()


def test_write_view_and_progress(tmp_path):
    folder = of.OutputFolder(tmp_path / "out")
    depth = np.random.default_rng(0).uniform(1, 2, (6, 8)).astype(np.float32)
    conf = np.full((6, 8), 0.5, np.float32)
    assert not folder.view_done(0, "s1")
    folder.write_view(0, depth, conf, "s1")
    assert folder.view_done(0, "s1") and not folder.view_done(0, "s2")
    np.testing.assert_array_equal(read_pfm(folder.paths(0)["depth"]), depth)
    assert Image.open(folder.paths(0)["depth_vis"]).size == (8, 6)
    assert json.loads((tmp_path / "out" / "progress.json").read_text())["views"] == {"0": "s1"}
    # A view whose file vanished is not done, whatever progress.json says.
    folder.paths(0)["confidence_vis"].unlink()
    assert not of.OutputFolder(tmp_path / "out").view_done(0, "s1")


def test_a_widened_search_range_is_recorded_with_its_view_by_every_rank(tmp_path):
    """The range stage 1 searched travels with the view's record: rank 1's through its own progress file into
    rank 0's, and a view written again with the camera's range forgets the wider one."""
    root = tmp_path / "out"
    depth, conf = np.ones((6, 8), np.float32), np.full((6, 8), 0.5, np.float32)
    main = of.OutputFolder(root)
    main.write_view(0, depth, conf, "s1", searched=(0.5, 9.0, 3.0))
    of.OutputFolder(root, rank=1).write_view(1, depth, conf, "s1", searched=(0.25, 20.0, 6.0))
    main = of.OutputFolder(root)  # the next start folds rank 1's record in
    assert main.progress["searched"] == {"0": [0.5, 9.0, 3.0], "1": [0.25, 20.0, 6.0]}
    assert not list(root.glob("progress.rank*"))
    of.OutputFolder(root, rank=1).write_view(1, depth, conf, "s2")
    main.write_view(0, depth, conf, "s2")
    main.fold_rank_progress()
    assert main.progress["searched"] == {}


def test_scene_fingerprint_and_refusal(tmp_path):
    a, b = of.scene_fingerprint(tiny_scene()), of.scene_fingerprint(tiny_scene(0.5))
    assert a != b and a == of.scene_fingerprint(tiny_scene())
    folder = of.OutputFolder(tmp_path)
    folder.check_scene(a)  # empty folder: fine
    folder.write_json("config.json", {"scene_fingerprint": a})
    folder.check_scene(a)
    with pytest.raises(InputError, match="different scene"):
        folder.check_scene(b)


def test_output_path_that_is_a_file(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        of.OutputFolder(tmp_path / "f")


def test_link_image_links_and_disk_full_is_reported(tmp_path, monkeypatch):
    src = tmp_path / "photo.PNG"
    src.write_bytes(b"123")
    folder = of.OutputFolder(tmp_path / "out")
    dst = folder.link_image(3, src)
    assert dst.name == "00000003.png" and dst.read_bytes() == b"123"
    assert dst.stat().st_ino == src.stat().st_ino  # a hard link on the same file system

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(of, "write_pfm", full)
    with pytest.raises(of.DiskFullError, match="disk is full"):
        folder.write_view(0, np.ones((2, 2)), np.ones((2, 2)), "s")
    assert not folder.view_done(0, "s")


def test_depth_previews_grey_what_fusion_drops_and_follow_a_new_threshold(tmp_path):
    folder = of.OutputFolder(tmp_path / "out")
    depth = np.full((6, 8), 2.0, np.float32)
    conf = np.broadcast_to(np.linspace(0.9, 0.1, 8, dtype=np.float32), (6, 8)).copy()
    folder.write_view(0, depth, conf, "s", preview_conf=0.5)

    def grey_columns():
        rgb = np.asarray(Image.open(tmp_path / "out" / "depth_vis" / "00000000.png")).astype(int)
        return [bool((rgb[:, c, 0] == rgb[:, c, 1]).all() and (rgb[:, c, 1] == rgb[:, c, 2]).all())
                for c in range(8)]

    assert grey_columns() == [bool(c <= 0.5) for c in conf[0]]  # fusion keeps conf > 0.5
    folder.redraw_previews([0], 0.5)  # the threshold the previews were drawn for: nothing to do
    folder.progress["preview_conf"] = 0.5
    folder.redraw_previews([0], 0.2)  # a rerun with --conf 0.2
    assert grey_columns() == [bool(c <= 0.2) for c in conf[0]]
    assert json.loads((tmp_path / "out" / "progress.json").read_text())["preview_conf"] == 0.2
