"""The output folder never destroys input, never mixes runs, and cleans up after killed or failed runs."""

import dataclasses
import errno
import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from mvsformerpp.cli import main
from mvsformerpp.errors import InputError
from mvsformerpp.io.detect import load_scene
from mvsformerpp.io.mvsnet import write_mvsnet_scene
from mvsformerpp.pipelines.reconstruct import reconstruct
from mvsformerpp.utils import output_guard

sys.path.insert(0, str(Path(__file__).parent))
from test_reconstruct import FAST, fake_model, outputs, temple_subset  # noqa: E402


@pytest.fixture
def mvs(tmp_path):
    """A small MVSNet scene folder of three views."""
    from mvsformerpp.synth import generate_scene

    return generate_scene(tmp_path / "mvs", seed=3, num_views=3, height=96, width=128, gt_points=1000)


@pytest.mark.parametrize("where", ["same", "inside", "parent"])
def test_output_folder_is_never_the_input(mvs, where):
    out = {"same": mvs, "inside": mvs / "out", "parent": mvs.parent}[where]
    before = outputs(mvs)
    with pytest.raises(InputError, match="input"):
        reconstruct(mvs, out, FAST, quiet=True, model=fake_model())
    assert outputs(mvs) == before and not (mvs / "out").exists()


def test_another_scene_folder_is_not_overwritten(mvs, tmp_path):
    other = write_mvsnet_scene(load_scene(temple_subset(tmp_path / "mid2", [5, 6])), tmp_path / "other")
    before = outputs(other)
    with pytest.raises(InputError, match="not empty and was not written by mvsformerpp reconstruct.*cams"):
        reconstruct(mvs, other, FAST, quiet=True, model=fake_model())
    assert outputs(other) == before


def test_synth_refuses_a_non_empty_folder(tmp_path, capsys):
    target = tmp_path / "mine"
    target.mkdir()
    (target / "notes.txt").write_text("keep me")
    rc = main(["synth", str(target), "--views", "2", "--height", "32", "--width", "32"])
    assert rc == 2 and "not empty" in capsys.readouterr().err
    assert [p.name for p in target.iterdir()] == ["notes.txt"]
    assert main(["synth", str(tmp_path / "new"), "--views", "2", "--height", "32", "--width", "32"]) == 0
    rc = main(["synth", str(tmp_path / "new"), "--views", "3", "--height", "32", "--width", "32"])
    assert rc == 2 and "other settings (num_views 2 -> 3)" in capsys.readouterr().err  # files would mix


def test_failed_run_leaves_no_empty_output_folder(mvs, tmp_path):
    (mvs / "images" / "00000001.png").unlink()
    with pytest.raises(InputError, match="no image"):
        reconstruct(mvs, tmp_path / "out", FAST, quiet=True, model=fake_model())
    assert not (tmp_path / "out").exists()


def test_orphan_temporaries_are_removed_and_outputs_honour_the_umask(mvs, tmp_path):
    out = tmp_path / "out"
    reconstruct(mvs, out, FAST, quiet=True, model=fake_model())
    orphans = [out / "depth_est" / ".00000000.pfm.k2j4x8aa.tmp", out / ".config.json.q1w2e3r4.tmp",
               out / "images" / ".00000001.png.link"]
    for p in orphans:
        p.write_bytes(b"half written")
    old = os.umask(0o027)
    try:
        reconstruct(mvs, out, dataclasses.replace(FAST, num_views=2), quiet=True, model=fake_model())
    finally:
        os.umask(old)
    assert not any(p.exists() for p in orphans)
    written = [*out.glob("depth_est/*"), *out.glob("depth_vis/*"), *out.glob("cams/*"), out / "config.json"]
    for p in written + [out / "progress.json"]:  # (images/ holds hard links to the input photos)
        assert p.stat().st_mode & 0o777 == 0o640, p


def test_unwritable_output_folder_is_one_clear_error(mvs, tmp_path, monkeypatch, capsys):
    (tmp_path / "a_file").write_text("x")
    rc = main(["reconstruct", str(mvs), "-o", str(tmp_path / "a_file" / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error:") and "which is a file, not a folder" in err and err.count("\n") == 1

    def read_only(self, *a, **kw):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(Path, "mkdir", read_only)
    with pytest.raises(InputError, match="Read-only file system"):
        reconstruct(mvs, tmp_path / "ro" / "out", FAST, quiet=True, model=fake_model())


RUNNER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, sys.argv[3])
    from test_reconstruct import FAST, fake_model
    from mvsformerpp.pipelines.reconstruct import reconstruct
    model = fake_model()
    forward = model.forward
    def slow(*a, **kw):
        time.sleep(1.0)
        return forward(*a, **kw)
    model.forward = slow
    reconstruct(sys.argv[1], sys.argv[2], FAST, quiet=True, model=model)
""")


def test_two_processes_into_one_folder(mvs, tmp_path, capsys):
    """The second run stops at once, names the first run's process, and the first finishes intact."""
    out = tmp_path / "out"
    first = subprocess.Popen([sys.executable, "-c", RUNNER, str(mvs), str(out), str(Path(__file__).parent)])
    lock = out / output_guard.LOCK
    deadline = time.monotonic() + 120
    while not (lock.is_file() and lock.read_text().strip()):
        assert first.poll() is None and time.monotonic() < deadline, "the first run did not start"
        time.sleep(0.05)
    rc = main(["reconstruct", str(mvs), "-o", str(out), "--views", "2", "--quiet"])
    err = capsys.readouterr().err
    assert first.wait(timeout=300) == 0
    assert rc == 2 and f"pid {first.pid} on " in err and "is writing to this folder" in err
    config = json.loads((out / "config.json").read_text())["config"]
    assert config["num_views"] == FAST.num_views  # the first run's settings, not the second's
    assert len(list((out / "depth_est").glob("*.pfm"))) == 3


def test_lock_is_released_after_a_run(tmp_path):
    with output_guard.claim_output_folder(tmp_path / "o"):
        pass
    with output_guard.claim_output_folder(tmp_path / "o"):  # a later run gets it
        pass


def test_kill_9_during_reconstruct_then_rerun_matches_an_uninterrupted_run(mvs, tmp_path):
    full = tmp_path / "full"
    cfg = dataclasses.replace(FAST, fusion="normal")
    reconstruct(mvs, full, cfg, quiet=True, model=fake_model())
    killed = tmp_path / "killed"
    runner = RUNNER.replace("FAST, quiet", "dataclasses.replace(FAST, fusion='normal'), quiet").replace(
        "import sys, time", "import dataclasses, sys, time")
    proc = subprocess.Popen([sys.executable, "-c", runner, str(mvs), str(killed), str(Path(__file__).parent)])
    deadline = time.monotonic() + 120
    while not (killed / "depth_est" / "00000000.pfm").is_file():
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.02)
    proc.kill()
    proc.wait()
    reconstruct(mvs, killed, cfg, quiet=True, model=fake_model())
    a, b = outputs(full), outputs(killed)
    skip = {"summary.json", "config.json", "report.html", output_guard.LOCK}  # (timings, folder names)
    assert {k for k in a if k not in skip} == {k for k in b if k not in skip}
    for name in a:
        if name not in skip:
            assert a[name] == b[name], name


def test_ranks_of_one_job_share_the_lock_of_rank_0(tmp_path, monkeypatch):
    out = tmp_path / "o"
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    with output_guard.claim_output_folder(out):
        monkeypatch.setenv("RANK", "1")
        with output_guard.claim_output_folder(out):  # rank 1 of the same job gets in
            pass
        monkeypatch.setenv("RANK", "0")
        with pytest.raises(output_guard.FolderBusyError):  # another job's rank 0 does not
            with output_guard.claim_output_folder(out):
                pass


@pytest.mark.parametrize("command", ["mesh", "report", "json", "plot", "error-ply"])
def test_no_command_overwrites_a_file_of_another_kind(synth_run, tmp_path, capsys, command):
    """mesh -o, report -o, evaluate --json/--plot/--error-ply replace only a file of the kind they write."""
    from mvsformerpp.cli import main
    from mvsformerpp.io.ply import write_ply
    from mvsformerpp.utils.file_kinds import MESH
    from mvsformerpp.utils.output_guard import check_replaceable

    photo = tmp_path / "photo.png"
    photo.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))  # a user's photo
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    cloud = str(synth_run / "fused.ply")
    args = {"mesh": ["mesh", str(synth_run), "-o", str(photo)],
            "report": ["report", str(synth_run), "-o", str(photo)],
            "json": ["evaluate", "cloud", cloud, cloud, "--threshold", "0.1", "--json", str(photo)],
            "plot": ["evaluate", "cloud", cloud, cloud, "--threshold", "0.1", "--plot", str(notes.with_suffix(".png"))],
            "error-ply": ["evaluate", "cloud", cloud, cloud, "--threshold", "0.1", "--error-ply",
                          str(tmp_path / "err.ply")]}[command]
    if command == "plot":
        notes.rename(notes.with_suffix(".png"))
        photo = notes.with_suffix(".png")
    if command == "error-ply":
        photo = tmp_path / "err_precision.ply"
        photo.write_text("not a cloud\n")
    before = photo.read_bytes()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "not overwritten" in err and photo.name in err
    assert photo.read_bytes() == before
    # a file of the command's own kind is replaced as before (the mesh's check: below, without meshing)
    if command in ("report", "json"):
        own = tmp_path / {"report": "r.html", "json": "r.json"}[command]
        args[args.index(str(photo))] = str(own)
        assert main(args) == 0 and main(args) == 0
    write_ply(tmp_path / "m.ply", np.zeros((3, 3)), faces=np.array([[0, 1, 2]]), kind=MESH)
    check_replaceable(tmp_path / "m.ply", MESH)
    with pytest.raises(InputError, match="did not write as a PLY mesh"):  # a point cloud is not a mesh
        check_replaceable(synth_run / "fused.ply", MESH)


def test_two_fuse_runs_into_one_file_of_a_plain_folder(synth_run, tmp_path, capsys):
    """The second stops at once and names the first (a lock beside the file, as no run folder holds it); the
    first's temporary is left alone; killed, the first leaves the next run nothing to trip over."""
    from test_input_checks import HANG_ON_FSYNC

    out = tmp_path / "plain" / "f.ply"
    full = tmp_path / "full.ply"
    assert main(["fuse", str(synth_run), "-o", str(full), "--quiet"]) == 0
    signal_file = tmp_path / "writing"
    first = subprocess.Popen([sys.executable, "-c", HANG_ON_FSYNC, str(signal_file), "fuse", str(synth_run), "-o",
                              str(out), "--quiet"])
    deadline = time.monotonic() + 120
    while not signal_file.exists():
        assert first.poll() is None and time.monotonic() < deadline, "the first run did not start"
        time.sleep(0.02)
    assert main(["fuse", str(synth_run), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"another mvsformerpp run (pid {first.pid} on " in err and "is writing this file" in err, err
    assert list(out.parent.glob(".f.ply.*.tmp"))  # (the first's cloud in progress, untouched)
    first.kill()
    first.wait()
    assert main(["fuse", str(synth_run), "-o", str(out), "--quiet"]) == 0
    assert out.read_bytes() == full.read_bytes()
    assert [p.name for p in out.parent.iterdir()] == ["f.ply"]  # no temporary, no lock left
