"""COLMAP export: read back with pycolmap, depth maps identical, COLMAP's own fusion runs on it; --overwrite
replaces a workspace only once the new one is whole, and a kill at any instant of that is recovered."""

import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.io.colmap_dense import read_colmap_array, write_colmap_array
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.pfm import read_pfm
from mvsformerpp.io.ply import ply_points, read_ply, read_ply_faces
from mvsformerpp.pipelines.export import export_colmap
from mvsformerpp.utils.atomic import current_umask


def test_array_format_matches_colmaps_reading_order(tmp_path):
    a = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)  # H=2, W=3, C=4
    write_colmap_array(tmp_path / "a.bin", a)
    raw = (tmp_path / "a.bin").read_bytes()
    assert raw.startswith(b"3&2&4&")
    # COLMAP's read_write_dense.py: fromfile, reshape (W, H, C) in Fortran order, transpose to (H, W, C)
    flat = np.frombuffer(raw[len(b"3&2&4&"):], np.float32)
    theirs = np.transpose(flat.reshape((3, 2, 4), order="F"), (1, 0, 2))
    assert np.array_equal(theirs, a)
    assert np.array_equal(read_colmap_array(tmp_path / "a.bin"), a)


def test_export_reads_back_with_pycolmap(synth_run, tmp_path, capsys):
    pycolmap = pytest.importorskip("pycolmap")
    ws = tmp_path / "ws"
    assert main(["export", str(synth_run), "--to", "colmap", str(ws)]) == 0
    assert "stereo_fusion" in capsys.readouterr().out
    rec = pycolmap.Reconstruction(ws / "sparse")
    scene = load_mvsnet_scene(synth_run)
    assert rec.num_images() == len(scene) and rec.num_cameras() == len(scene)
    names = (ws / "stereo" / "fusion.cfg").read_text().split()
    for image in rec.images.values():
        view = scene.views[names.index(image.name)]
        cam = rec.cameras[image.camera_id]
        assert cam.model.name == "PINHOLE" and (cam.width, cam.height) == (view.width, view.height)
        assert np.allclose(cam.calibration_matrix(), view.K)
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        assert np.allclose(pose.rotation.matrix(), view.R, atol=1e-9) and np.allclose(pose.translation, view.t)
        ours = read_pfm(synth_run / "depth_est" / f"{view.name}.pfm")
        theirs = pycolmap.DepthMap()
        theirs.read(ws / "stereo" / "depth_maps" / f"{image.name}.geometric.bin")
        assert np.array_equal(theirs.to_array(), ours)
        normals = read_colmap_array(ws / "stereo" / "normal_maps" / f"{image.name}.geometric.bin")
        assert normals.shape == (*ours.shape, 3)
        assert (ws / "images" / image.name).is_file()
    frustums = read_ply_faces(ws / "cameras.ply")
    assert len(frustums) == 6 * len(scene) and len(ply_points(read_ply(ws / "cameras.ply"))) == 5 * len(scene)
    # COLMAP's own depth-map fusion accepts the workspace and puts its points on our surface
    fused = tmp_path / "colmap_fused.ply"
    options = pycolmap.StereoFusionOptions()
    options.min_num_pixels = 2
    pycolmap.stereo_fusion(fused, ws, options=options, output_type="PLY")
    pts = ply_points(read_ply(fused))
    ours = ply_points(read_ply(synth_run / "fused.ply"))
    assert len(pts) > 1000
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(ours).query(pts)
    assert np.median(dist) < 0.01 * np.median([v.depth_min for v in scene.views])


def test_export_refuses_a_non_empty_folder(synth_run, tmp_path, capsys):
    ws = tmp_path / "ws"
    ws.mkdir()
    (ws / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="--overwrite"):
        export_colmap(synth_run, ws, quiet=True)
    assert (ws / "keep.txt").read_text() == "mine"
    # --overwrite replaces an earlier export, never a folder of the user's own files
    assert main(["export", str(synth_run), "--to", "colmap", str(ws), "--overwrite", "--quiet"]) == 2
    assert "replaces only an empty folder or one that mvsformerpp export wrote" in capsys.readouterr().err
    assert (ws / "keep.txt").read_text() == "mine"
    ws2 = tmp_path / "ws2"
    assert main(["export", str(synth_run), "--to", "colmap", str(ws2), "--quiet"]) == 0
    (ws2 / "sparse" / "stale.txt").write_text("from before")
    assert main(["export", str(synth_run), "--to", "colmap", str(ws2), "--overwrite", "--quiet"]) == 0
    assert not (ws2 / "sparse" / "stale.txt").exists() and (ws2 / "sparse" / "cameras.bin").is_file()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary left
    assert main(["export", str(tmp_path / "nothing"), "--to", "colmap", str(tmp_path / "ws3")]) == 2
    assert "mvsformerpp reconstruct" in capsys.readouterr().err


def test_overwrite_never_deletes_the_reconstruction_or_the_photos(synth_run, tmp_path, capsys):
    import shutil

    parent = tmp_path / "parent"
    out = parent / "out"
    shutil.copytree(synth_run, out, symlinks=True)
    for p in (parent / "images", parent / "sparse", parent / "stereo"):
        p.mkdir()  # looks like a workspace, and it holds the reconstruction
    assert main(["export", str(out), "--to", "colmap", str(parent), "--overwrite", "--quiet"]) == 2
    assert f"contains the input {out}" in capsys.readouterr().err and (out / "depth_est").is_dir()
    photos = tmp_path / "shoot" / "images"  # the photos the run read, linked from OUT/images as reconstruct does
    photos.mkdir(parents=True)
    for link in sorted((out / "images").iterdir()):
        shutil.move(link.resolve(), photos / link.name)
        link.unlink(missing_ok=True)
        link.symlink_to(photos / link.name)
    for sub in ("sparse", "stereo"):  # their folder looks like a workspace (an earlier export read back)
        (photos.parent / sub).mkdir()
    assert main(["export", str(out), "--to", "colmap", str(photos.parent), "--overwrite", "--quiet"]) == 2
    assert f"contains the input {photos}" in capsys.readouterr().err
    assert photos.is_dir() and any(photos.iterdir())


# Runs the command line, but kills itself with SIGKILL at one instant of putting the new workspace in place:
# before the old one is renamed aside, before the new one is renamed in, or before the old one is deleted.
KILL_IN_SWAP = textwrap.dedent("""
    import os, shutil, signal, sys
    instant = sys.argv.pop(1)
    real_rename, real_rmtree, renames = os.rename, shutil.rmtree, [0]
    def rename(a, b):
        renames[0] += 1
        if (instant, renames[0]) in (("aside", 1), ("rename-in", 2)):
            os.kill(os.getpid(), signal.SIGKILL)
        return real_rename(a, b)
    def rmtree(path, *args, **kw):
        if instant == "delete-old" and str(path).endswith(".previous"):
            os.kill(os.getpid(), signal.SIGKILL)
        return real_rmtree(path, *args, **kw)
    os.rename, shutil.rmtree = rename, rmtree
    from mvsformerpp.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _kill_during_overwrite_then_rerun(synth_run, tmp_path, instant):
    ws = tmp_path / "ws"
    command = ["export", str(synth_run), "--to", "colmap", str(ws), "--overwrite", "--quiet"]
    assert main(command) == 0
    new = _tree(ws)
    (ws / "sparse" / "from_before.txt").write_text("the old workspace")
    old = _tree(ws)
    proc = subprocess.run([sys.executable, "-c", KILL_IN_SWAP, instant, *command], timeout=600)
    assert proc.returncode == -signal.SIGKILL
    left = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".ws."))
    assert left, "the kill left nothing to recover from"
    if instant == "aside":  # the old workspace is still in place
        assert _tree(ws) == old
    if instant == "rename-in":  # no workspace under its name: the old one waits aside
        assert not ws.exists() and ".ws.previous" in left
    assert main(command) == 0  # the same command recovers
    assert _tree(ws) == new
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert (ws.stat().st_mode & 0o777) == 0o777 & ~current_umask()


def test_export_overwrite_killed_between_its_renames_is_recovered_by_the_same_command(synth_run, tmp_path):
    _kill_during_overwrite_then_rerun(synth_run, tmp_path, "rename-in")


@pytest.mark.slow
@pytest.mark.parametrize("instant", ["aside", "delete-old"])
def test_export_overwrite_killed_at_its_other_instants_is_recovered(synth_run, tmp_path, instant):
    _kill_during_overwrite_then_rerun(synth_run, tmp_path, instant)
