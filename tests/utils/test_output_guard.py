"""The output guard's parts: file kinds and their markers, names from data, locks, interrupts held back, folders
replaced by renames and the recovery of a killed replacement."""

import json
import os
import signal

import numpy as np
import pytest

from mvsformerpp.errors import InputError
from mvsformerpp.io.ply import write_ply
from mvsformerpp.utils import file_kinds as K
from mvsformerpp.utils.file_kinds import PLY_MARKER
from mvsformerpp.utils.interrupts import deferred_interrupt
from mvsformerpp.utils.output_guard import (
    MARKER,
    check_replaceable,
    child,
    claim_output_file,
    claim_output_folder,
)
from mvsformerpp.utils.output_tree import claim_output_tree

PLY_KINDS = [K.POINT_CLOUD, K.MESH, K.ERROR_CLOUD, K.GT_SURFACE, K.CAMERA_FRUSTUMS]


@pytest.mark.parametrize("kind", PLY_KINDS, ids=[k.what for k in PLY_KINDS])
def test_a_ply_is_recognised_as_the_kind_it_was_written_as_and_no_other(tmp_path, kind):
    path = tmp_path / "x.ply"
    write_ply(path, np.zeros((3, 3)), faces=np.array([[0, 1, 2]]), kind=kind)
    assert [k.what for k in PLY_KINDS if k.written_here(path)] == [kind.what]


def test_a_cloud_of_an_earlier_version_counts_as_a_point_cloud_only(tmp_path):
    path = tmp_path / "old.ply"
    write_ply(path, np.zeros((3, 3)))
    path.write_bytes(path.read_bytes().replace(K.POINT_CLOUD.marker, (PLY_MARKER + "\n").encode()))
    assert [k.what for k in PLY_KINDS if k.written_here(path)] == ["PLY point cloud"]
    foreign = tmp_path / "theirs.ply"  # the same format, another writer
    foreign.write_bytes(path.read_bytes().replace((PLY_MARKER + "\n").encode(), b"comment made elsewhere\n"))
    assert not any(k.written_here(foreign) for k in PLY_KINDS) and K.POINT_CLOUD.has_format(foreign)


@pytest.mark.parametrize("fmt", list(K.PLOT_FORMATS))
def test_every_plot_format_carries_the_marker(tmp_path, fmt):
    pytest.importorskip("matplotlib")
    from mvsformerpp.evaluation.visualize import plot_pr_curves

    path = tmp_path / f"curve.{fmt}"
    curve = {"thresholds": np.linspace(0.1, 1, 5), **{k: np.linspace(0, 1, 5) for k in ("precision", "recall",
                                                                                         "f_score")}}
    plot_pr_curves(path, curve, 0.5)
    assert K.plot_kind(fmt).written_here(path)
    plot_pr_curves(path, curve, 0.5)  # its own plot is replaced
    photo = tmp_path / f"photo.{fmt}"
    photo.write_bytes(path.read_bytes().replace(K.PLOT_MARKER.encode(), b"some other program!!"))
    with pytest.raises(InputError, match="did not write as .* plot"):
        plot_pr_curves(photo, curve, 0.5)


def test_evaluation_json_and_error_clouds_are_marked_and_replaced_by_a_rerun(tmp_path):
    from mvsformerpp.cli import main

    write_ply(tmp_path / "p.ply", np.random.default_rng(0).uniform(0, 1, (50, 3)))
    write_ply(tmp_path / "g.ply", np.random.default_rng(1).uniform(0, 1, (50, 3)))
    clouds = [str(tmp_path / "p.ply"), str(tmp_path / "g.ply")]
    for _ in range(2):
        assert main(["evaluate", "cloud", *clouds, "--threshold", "0.1", "--json", str(tmp_path / "m.json"),
                     "--error-ply", str(tmp_path / "e.ply")]) == 0
        assert main(["evaluate", "eth3d", *clouds, "--tolerances", "0.1", "--json", str(tmp_path / "t.json")]) == 0
    record = json.loads((tmp_path / "m.json").read_text())
    assert record["written_by"] == K.JSON_MARKER and 0 <= record["precision"] <= 1
    table = json.loads((tmp_path / "t.json").read_text())
    assert table["written_by"] == K.JSON_MARKER and [r["tolerance"] for r in table["tolerances"]] == [0.1]
    assert K.ERROR_CLOUD.written_here(tmp_path / "e_precision.ply")


def test_a_run_folders_own_names_go_to_their_kind_for_that_run_only(tmp_path):
    runs = [tmp_path / "a", tmp_path / "b"]
    for run in runs:
        run.mkdir()
        (run / MARKER).write_text(json.dumps({"written_by": "mvsformerpp reconstruct"}))
    check_replaceable(runs[0] / "fused.ply", K.POINT_CLOUD, run=runs[0])  # fuse a: a/fused.ply, new
    with pytest.raises(InputError, match="fused.ply is the run's own PLY point cloud"):
        check_replaceable(runs[0] / "fused.ply", K.MESH, run=runs[0])  # (even while it does not exist)
    with pytest.raises(InputError, match="own PLY point cloud of the run in"):
        check_replaceable(runs[1] / "fused.ply", K.POINT_CLOUD, run=runs[0])  # fuse a -o b/fused.ply
    check_replaceable(runs[1] / "mesh.ply", K.MESH, run=runs[0])  # any other name is free


@pytest.mark.parametrize("name", ["", ".", "..", "../x", "a/../../x", ".hidden", "/etc/passwd"])
def test_names_from_data_stay_inside_their_folder(tmp_path, name):
    with pytest.raises(InputError, match="scene name"):
        child(tmp_path, name, "scene name")


def test_plain_names_from_data_are_accepted(tmp_path):
    assert child(tmp_path, "Barn.ply", "scene name") == tmp_path / "Barn.ply"
    assert child(tmp_path, "sub/x.png", "view name") == tmp_path / "sub" / "x.png"


def test_ctrl_c_in_a_held_back_block_lets_it_finish_then_stops():
    steps = []
    with pytest.raises(KeyboardInterrupt):
        with deferred_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            steps.append("after the signal")
    assert steps == ["after the signal"] and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with deferred_interrupt():  # no signal, no interrupt
        steps.append("quiet")
    assert steps[-1] == "quiet"


def test_a_file_claim_cleans_what_a_killed_run_left_and_leaves_nothing(tmp_path):
    out = tmp_path / "plain" / "c.ply"
    out.parent.mkdir()
    leftovers = [out.parent / ".c.ply.k2j4x8aa.tmp", out.parent / ".c.ply.lock"]  # a killed run's
    for p in leftovers:
        p.write_bytes(b"half")
    with claim_output_file(out, K.POINT_CLOUD):
        assert not leftovers[0].exists()  # (the lock file is this run's now)
        write_ply(out, np.zeros((2, 3)))
    assert sorted(p.name for p in out.parent.iterdir()) == ["c.ply"]
    with pytest.raises(InputError, match="not a PLY point cloud"), claim_output_file(tmp_path / "a" / "b" / "x.html",
                                                                                    K.POINT_CLOUD):
        raise InputError("not a PLY point cloud")  # (a failure inside the claim)
    assert not (tmp_path / "a").exists()  # the folders it made for nothing are gone


def _workspace(path, text):
    path.mkdir()
    (path / MARKER).write_text(json.dumps({"written_by": "mvsformerpp export"}))
    (path / "what.txt").write_text(text)


def test_a_replacement_killed_with_the_old_folder_aside_is_undone_then_done(tmp_path):
    target = tmp_path / "ws"
    _workspace(tmp_path / ".ws.previous", "old")  # killed after renaming the old one aside
    _workspace(tmp_path / ".ws.abcd1234.tmp", "half new")  # its staged folder
    (tmp_path / ".ws.zzzz9999.tmp").mkdir()  # a folder of that name that is not this package's: left alone
    with pytest.raises(InputError, match="not empty; choose another DIR or pass --overwrite"):
        with claim_output_tree(target, "export"):
            pass
    assert (target / "what.txt").read_text() == "old"  # put back before anything else
    assert sorted(p.name for p in tmp_path.iterdir()) == [".ws.zzzz9999.tmp", "ws"]
    with claim_output_tree(target, "export", overwrite=True) as staging:
        (staging / "what.txt").write_text("new")
        assert (target / "what.txt").read_text() == "old"  # the old one stays until the new one is whole
    assert (target / "what.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".ws.zzzz9999.tmp", "ws"]


def test_a_replacement_killed_after_the_new_folder_went_in_finishes(tmp_path):
    target = tmp_path / "ws"
    _workspace(target, "new")
    _workspace(tmp_path / ".ws.previous", "old")
    with pytest.raises(RuntimeError, match="stop"), claim_output_tree(target, "export", overwrite=True):
        raise RuntimeError("stop")  # (a failed export: the workspace in place stays)
    assert (target / "what.txt").read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["ws"]


def _python_writers(run, scene_dir):
    """Every Python function of the package that writes an output, aimed at ``target`` (a path)."""
    import mvsformerpp
    from mvsformerpp.evaluation.tnt_submission import package_tnt_submission
    from mvsformerpp.evaluation.visualize import plot_pr_curves, write_error_ply
    from mvsformerpp.pipelines.export import export_colmap
    from mvsformerpp.pipelines.mesh import make_mesh
    from mvsformerpp.pipelines.train import run_training
    from mvsformerpp.synth import generate_dataset, generate_scene
    from mvsformerpp.viewer.report import write_report

    from ..training.train_utils import tiny_config

    points = np.zeros((3, 3))
    curve = {k: np.linspace(0.1, 1, 3) for k in ("thresholds", "precision", "recall", "f_score")}
    return {
        "reconstruct": lambda t: mvsformerpp.reconstruct(scene_dir, t, quiet=True),
        "fuse": lambda t: mvsformerpp.fuse(run, t / "c.ply", quiet=True),
        "make_mesh": lambda t: make_mesh(run, t / "m.ply", quiet=True),
        "write_report": lambda t: write_report(run, t / "r.html"),
        "export_colmap": lambda t: export_colmap(run, t, quiet=True),
        "generate_scene": lambda t: generate_scene(t, num_views=2, height=32, width=32),
        "generate_dataset": lambda t: generate_dataset(t, 2, num_views=2, height=32, width=32),
        "package_tnt_submission": lambda t: package_tnt_submission(t, {"Barn": (run / "fused.ply", np.eye(4)[None])}),
        "write_error_ply": lambda t: write_error_ply(t / "e.ply", points, np.zeros(3), 1.0),
        "plot_pr_curves": lambda t: plot_pr_curves(t / "p.png", curve),
        "run_training": lambda t: run_training(tiny_config(max_steps=1), t),
    }


@pytest.mark.parametrize("writer", ["reconstruct", "fuse", "make_mesh", "write_report", "export_colmap",
                                    "generate_scene", "generate_dataset", "package_tnt_submission", "write_error_ply",
                                    "plot_pr_curves", "run_training"])
def test_python_writers_are_guarded_as_the_commands_are(synth_run, writer):
    """The guard sits in the functions, not the command line: aimed into the installed package, each refuses."""
    from mvsformerpp.utils.output_guard import package_root

    target = package_root() / "assets" / "not_here"
    with pytest.raises(InputError, match="inside the installed mvsformerpp package"):
        _python_writers(synth_run, synth_run.parent / "scene")[writer](target)
    assert not target.exists()


def test_a_setting_added_after_the_run_reads_as_none_and_an_extra_one_is_named(tmp_path):
    out = tmp_path / "set"
    with claim_output_folder(out, kind="synth", settings={"seed": 3, "textures": None}):
        (out / "scene.json").write_text("{}")
    marker = out / MARKER
    record = json.loads(marker.read_text())
    del record["settings"]["textures"]  # as a version without the setting wrote it
    record["settings"]["retired"] = 1
    marker.write_text(json.dumps(record))
    with pytest.raises(InputError, match=r"other settings \(retired 1 -> \(none\)\)"):
        with claim_output_folder(out, kind="synth", settings={"seed": 3, "textures": None}):
            pass
    del record["settings"]["retired"]
    marker.write_text(json.dumps(record))
    with claim_output_folder(out, kind="synth", settings={"seed": 3, "textures": None}):
        pass  # completes the older run
    with pytest.raises(InputError, match=r"other settings \(textures None -> 'lib'\)"):
        with claim_output_folder(out, kind="synth", settings={"seed": 3, "textures": "lib"}):
            pass
