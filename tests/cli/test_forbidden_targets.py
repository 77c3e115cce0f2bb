"""Every writer of the command line against one table of places it must never write (the output guard).

Writers: each command and option that writes a file or a folder. Targets: inside the installed package, an
input of the command, a file or folder of another run (or of the run read, of another kind), a file of the
user's of the same format, a path under a file, a name longer than the file system allows, a file where a
folder goes (or a folder where a file goes), and a symbolic link to an input. Every pair where the writer can
aim at the target runs the command: exit 2, one ``error:`` line, and not a byte changed in the test's folder or
in the package.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
import bad_inputs  # noqa: E402

from mvsformerpp.utils.output_guard import LOCK, MARKER, package_root  # noqa: E402


@dataclass(frozen=True)
class Env:
    root: Path
    scene: Path  # a synthetic scene (MVSNet layout): reconstruct's input
    run: Path  # a reconstruct output folder: fuse, mesh, report, export read it
    train_run: Path  # a training run folder
    clouds: Path  # pred.ply, gt.ply, Barn.log: evaluate's and tnt-submit's inputs
    recipe: Path  # exp/config.yaml: train's input
    dtu: Path  # DTU evaluation data of scan 1
    dtu_pred: Path  # a folder with mvsnet001_l3.ply
    mine: Path  # a folder of the user's own files

    @property
    def pred(self) -> Path:
        return self.clouds / "pred.ply"


@pytest.fixture(scope="module")
def env(tmp_path_factory) -> Env:
    import scipy.io

    from mvsformerpp.cli import main
    from mvsformerpp.evaluation.tnt_submission import write_log
    from mvsformerpp.io.ply import write_ply

    d = tmp_path_factory.mktemp("targets")
    scene = bad_inputs.scene(d)
    run = bad_inputs.fused_folder(d / "r")
    run = run.rename(d / "run")
    (run / MARKER).write_text(json.dumps({"written_by": "mvsformerpp reconstruct"}))
    (run / "config.json").write_text(json.dumps({"config": {"preset": "lite"}, "input": str(scene)}))
    assert main(["fuse", str(run), "--quiet"]) == 0 and main(["report", str(run)]) == 0
    train_run = d / "train_run"
    train_run.mkdir()
    (train_run / "config.yaml").write_text("recipe: synthetic\n")
    (train_run / "metrics.jsonl").write_text('{"step": 1}\n')
    clouds = d / "clouds"
    clouds.mkdir()
    rng = np.random.default_rng(0)
    write_ply(clouds / "pred.ply", rng.uniform(0, 1, (300, 3)))
    write_ply(clouds / "gt.ply", rng.uniform(0, 1, (300, 3)))
    shutil.copy(clouds / "pred.ply", clouds / "pred_precision.ply")
    write_log(clouds / "Barn.log", np.eye(4)[None].repeat(2, 0))
    (d / "exp").mkdir()
    recipe = d / "exp" / "config.yaml"
    recipe.write_text("recipe: synthetic\nmax_steps: 1\n")
    dtu = d / "dtu"
    (dtu / "ObsMask").mkdir(parents=True)
    (dtu / "Points" / "stl").mkdir(parents=True)
    scipy.io.savemat(dtu / "ObsMask" / "ObsMask1_10.mat", {"ObsMask": np.ones((30, 30, 10), bool),
                                                            "BB": np.array([[-5.0, -5, -5], [25, 25, 5]]), "Res": 1.0})
    scipy.io.savemat(dtu / "ObsMask" / "Plane1.mat", {"P": np.array([[0.0], [0], [1], [1]])})
    write_ply(dtu / "Points" / "stl" / "stl001_total.ply", rng.uniform(0, 20, (300, 3)))
    (d / "preds").mkdir()
    write_ply(d / "preds" / "mvsnet001_l3.ply", rng.uniform(0, 20, (300, 3)))
    mine = d / "mine"
    mine.mkdir()
    foreign_ply = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n" \
                  b"end_header\n0 0 0\n"
    for name, data in {"cloud.ply": foreign_ply, "cloud_precision.ply": foreign_ply, "notes.json": b'{"a": 1}\n',
                       "photo.png": (scene / "images" / "00000000.png").read_bytes(),
                       "page.html": b"<!DOCTYPE html><html><body>mine</body></html>\n"}.items():
        (mine / name).write_bytes(data)
    (mine / "errors").mkdir()
    (mine / "errors" / "scan1_accuracy.ply").write_bytes(foreign_ply)
    for suffix in {w.suffix for w in WRITERS if not w.folder}:
        (d / f"folder{suffix}").mkdir()
    return Env(d, scene, run, train_run, clouds, recipe, dtu, d / "preds", mine)


# ------------------------------------------------------------------------------------------- the writers
@dataclass(frozen=True)
class Writer:
    name: str
    folder: bool
    """It writes a folder (else a file)."""
    argv: Callable[[Env, Path], list[str]]
    """The command line that writes the given path."""
    suffix: str = ""
    """File writers: how the name of the file it writes ends."""
    input_target: Callable[[Env], Path] | None = None
    """An input of the command that it could be aimed at (None: it reads none it could write)."""
    own_target: Callable[[Env], Path] | None = None
    """A file or folder of a run of another kind or of the run read (None: no such place it could take)."""


def _cloud(env: Env, *extra: str) -> list[str]:
    return ["evaluate", "cloud", str(env.pred), str(env.clouds / "gt.ply"), "--threshold", "0.1", *extra]


def _error_ply(p: Path) -> Path:
    """The ``--error-ply`` that makes ``evaluate`` write ``p`` (which ends with ``_precision.ply``)."""
    assert p.name.endswith("_precision.ply"), p
    return p.with_name(p.name[:-len("_precision.ply")] + ".ply")


WRITERS = [
    Writer("reconstruct", True, lambda e, p: ["reconstruct", str(e.scene), "-o", str(p), "--preset", "lite", "--quiet"],
           input_target=lambda e: e.scene, own_target=lambda e: e.train_run),
    Writer("demo", True, lambda e, p: ["demo", "-o", str(p), "--quiet"],
           input_target=lambda e: package_root() / "assets" / "templeSparseRing", own_target=lambda e: e.train_run),
    Writer("fuse", False, lambda e, p: ["fuse", str(e.run), "-o", str(p), "--mask-dir", str(e.scene / "masks"),
                                        "--quiet"], ".ply",
           input_target=lambda e: e.scene / "masks" / "fused.ply", own_target=lambda e: e.run / "report.html"),
    Writer("mesh", False, lambda e, p: ["mesh", str(e.run), "-o", str(p), "--quiet"], ".ply",
           input_target=lambda e: e.run / "fused.ply", own_target=lambda e: e.run / "fused.ply"),
    Writer("report", False, lambda e, p: ["report", str(e.run), "-o", str(p)], ".html",
           input_target=lambda e: e.run / "config.json", own_target=lambda e: e.run / "fused.ply"),
    Writer("export", True, lambda e, p: ["export", str(e.run), "--to", "colmap", str(p), "--overwrite", "--quiet"],
           input_target=lambda e: e.scene, own_target=lambda e: e.train_run),
    Writer("evaluate --json", False, lambda e, p: _cloud(e, "--json", str(p)), ".json",
           input_target=lambda e: e.pred, own_target=lambda e: e.run / "config.json"),
    Writer("evaluate --plot", False, lambda e, p: _cloud(e, "--plot", str(p)), ".png",
           input_target=lambda e: e.pred, own_target=lambda e: e.run / "images" / "00000000.png"),
    Writer("evaluate --error-ply", False,  # (its prediction is named as the error cloud it writes would be)
           lambda e, p: ["evaluate", "cloud", str(e.clouds / "pred_precision.ply"), str(e.clouds / "gt.ply"),
                         "--threshold", "0.1", "--error-ply", str(_error_ply(p))], "_precision.ply",
           input_target=lambda e: e.clouds / "pred_precision.ply"),
    Writer("evaluate dtu --error-ply-dir", True,
           lambda e, p: ["evaluate", "dtu", str(e.dtu_pred), "--dtu-root", str(e.dtu), "--scans", "1",
                         "--error-ply-dir", str(p)], input_target=lambda e: e.dtu),
    Writer("evaluate tnt-submit", True,
           lambda e, p: ["evaluate", "tnt-submit", str(p), "Barn", str(e.pred), str(e.clouds / "Barn.log")],
           input_target=lambda e: e.clouds, own_target=lambda e: e.run),
    Writer("synth", True, lambda e, p: ["synth", str(p), "--views", "2", "--height", "32", "--width", "32"],
           own_target=lambda e: e.run),
    Writer("train", True, lambda e, p: ["train", str(e.recipe), "-o", str(p)],
           input_target=lambda e: e.recipe.parent, own_target=lambda e: e.run),
]


# ------------------------------------------------------------------------------------------- the targets
def _in_package(env: Env, w: Writer) -> Path:
    assets = package_root() / "assets"
    if w.folder:
        return assets / "new_output"
    return {".json": assets / "weights" / "default.json",
            ".png": assets / "templeSparseRing" / "templeSR0001.png"}.get(w.suffix, assets / f"new{w.suffix}")


def _users_own(env: Env, w: Writer) -> Path | None:
    if w.folder:
        return env.mine / "errors" if w.name.endswith("--error-ply-dir") else env.mine
    return env.mine / {".ply": "cloud.ply", "_precision.ply": "cloud_precision.ply", ".json": "notes.json",
                       ".png": "photo.png", ".html": "page.html"}[w.suffix]


def _symlink_to_input(env: Env, w: Writer) -> Path | None:
    if w.input_target is None:
        return None
    aim = w.input_target(env)
    link = env.root / "links" / (f"{w.name.replace(' ', '_')}{w.suffix if not w.folder else ''}")
    if w.suffix == "_precision.ply":
        link = link.with_name("link_precision.ply")
    link.parent.mkdir(exist_ok=True)
    if not os.path.lexists(link):
        link.symlink_to(aim)
    return link


TARGETS: dict[str, Callable[[Env, Writer], Path | None]] = {
    "inside the installed package": _in_package,
    "an input": lambda e, w: w.input_target(e) if w.input_target else None,
    "another run's or another kind's own file": lambda e, w: w.own_target(e) if w.own_target else None,
    "a file or folder of the user's": _users_own,
    "under a file": lambda e, w: e.scene / "pair.txt" / f"x{w.suffix}",
    "a name over 255 bytes": lambda e, w: e.root / f"{'a' * 300}{w.suffix}",
    "a folder for a file, a file for a folder": lambda e, w: Path("/dev/null") if w.folder else
    e.root / f"folder{w.suffix}",
    "a symbolic link to an input": _symlink_to_input,
}
NEEDS = {"an input": "input_target", "another run's or another kind's own file": "own_target",
         "a symbolic link to an input": "input_target"}
"""Targets that only writers with such a place have."""
PAIRS = [(w, t) for w in WRITERS for t in TARGETS if getattr(w, NEEDS.get(t, "name")) is not None]


def _snapshot(*roots: Path) -> dict[str, tuple[int, int, int]]:
    """Every file and folder under ``roots`` (the folders' locks and Python's byte-code caches aside): size, inode,
    modification time."""
    seen = {}
    for root in roots:
        for dirpath, dirs, files in os.walk(root):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for name in dirs + files:
                p = os.path.join(dirpath, name)
                if name != LOCK:
                    st = os.lstat(p)
                    seen[p] = (st.st_size if name in files else 0, st.st_ino, st.st_mtime_ns)
    return seen


@pytest.mark.parametrize("writer,target", PAIRS, ids=[f"{w.name}|{t}" for w, t in PAIRS])
def test_no_writer_writes_a_forbidden_target(env, writer, target):
    from mvsformerpp.cli import main

    aim = TARGETS[target](env, writer)
    before = _snapshot(env.root, package_root())
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main(writer.argv(env, aim))
    message = err.getvalue()
    assert rc == 2 and message.startswith("error: ") and message.count("\n") == 1, message
    assert _snapshot(env.root, package_root()) == before, message


def test_the_table_reaches_every_writer_with_most_targets():
    """Each writer meets at least six of the eight targets (those it has no way to reach are left out)."""
    for w in WRITERS:
        assert sum(1 for pw, _ in PAIRS if pw is w) >= 6, w.name
