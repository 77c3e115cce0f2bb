"""Bad inputs and the one-line message each gets: the cases behind ``docs/bad-inputs.md``.

Every case builds its files in an empty folder, runs the ``mvsformerpp`` command in process and
records the exit code and what it printed on stderr. ``test_bad_inputs.py`` checks each case (non-zero
exit, exactly one ``error:`` line, the expected words, no traceback) and that the table in
``docs/bad-inputs.md`` shows exactly the message the command prints today. Regenerate the table with

    python tests/cli/bad_inputs.py --write docs/bad-inputs.md
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "bad-inputs.md"


@dataclass(frozen=True)
class Case:
    id: str
    what: str
    """The bad input, in words."""
    build: Callable[[Path], list[str]]
    """Creates the files under the given folder and returns the command's arguments (after ``mvsformerpp``)."""
    expect: str
    """Words the message must contain (a regular expression)."""
    patch: Callable[[object], None] | None = None
    """Applies a fault (e.g. a full disk) with a pytest MonkeyPatch."""
    needs_no_cuda: bool = False


# --------------------------------------------------------------------------------------- fixtures
_CACHE: dict[str, Path] = {}


def _cached(name: str, make: Callable[[Path], None]) -> Path:
    if name not in _CACHE:
        root = Path(tempfile.mkdtemp(prefix="mvsformerpp-bad-inputs-"))
        make(root / name)
        _CACHE[name] = root / name
    return _CACHE[name]


def scene(d: Path, name: str = "scene") -> Path:
    """A small MVSNet scene (synthetic, 3 views of 96x64) copied to ``d/name``."""
    from mvsformerpp.synth import generate_scene

    src = _cached("mvs", lambda p: generate_scene(p, seed=2, num_views=3, height=64, width=96, gt_points=500))
    return Path(shutil.copytree(src, d / name))


def fused_folder(d: Path) -> Path:
    """A scene folder with depth_est/ and confidence/ (the ground truth as depth, confidence 0.9)."""
    from mvsformerpp.io.pfm import read_pfm, write_pfm

    s = scene(d)
    for p in sorted((s / "depth_gt").glob("*.pfm")):
        depth = read_pfm(p)
        write_pfm(s / "depth_est" / p.name, depth)
        write_pfm(s / "confidence" / p.name, np.full_like(depth, 0.9))
    return s


def reconstruction(d: Path, recorded_input: Path | None = None) -> Path:
    """A ``reconstruct`` output folder ``d/run``: depth maps, the run's marker and record (its input:
    ``recorded_input``), and its fused cloud."""
    import json

    from mvsformerpp.cli import main

    run = fused_folder(d).rename(d / "run")
    (run / ".mvsformerpp").write_text(json.dumps({"written_by": "mvsformerpp reconstruct"}) + "\n")
    record = {"config": {"preset": "lite"}, "input": str(recorded_input or d / "input")}
    (run / "config.json").write_text(json.dumps(record) + "\n")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["fuse", str(run), "--quiet"]) == 0
    return run


def quietly(*argv: str) -> None:
    """Run a command that sets a case up (it must succeed)."""
    from mvsformerpp.cli import main

    with contextlib.redirect_stdout(io.StringIO()):
        assert main(list(argv)) == 0, argv


def package_file(*parts: str) -> Path:
    from mvsformerpp.utils.output_guard import package_root

    return package_root().joinpath(*parts)


def cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def cloud(path: Path, n: int = 200, seed: int = 0) -> Path:
    from mvsformerpp.io.ply import write_ply

    xyz = np.random.default_rng(seed).uniform(0, 1, (n, 3)).astype(np.float32)
    write_ply(path, xyz)
    return path


def colmap_project(d: Path, points: bool = True, empty_points: bool = False) -> Path:
    sys.path.insert(0, str(ROOT / "tests" / "io"))
    from colmap_synth import synthetic_model, write_photos

    from mvsformerpp.io.colmap_model import write_model

    model = synthetic_model(n_views=3, width=64, height=48)
    project = d / "colmap"
    write_model(model, project / "sparse" / "0", ext=".txt")
    write_photos(model, project / "images")
    pts = project / "sparse" / "0" / "points3D.txt"
    if not points:
        pts.unlink()
    elif empty_points:
        pts.write_text("# 3D point list with one line of data per point:\n# Number of points: 0\n")
    return project


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new, 1))


def recon(d: Path, *extra: str, src: Path | None = None, out: Path | None = None) -> list[str]:
    src = src if src is not None else scene(d)
    return ["reconstruct", str(src), "-o", str(out if out is not None else d / "out"), "--preset", "lite",
            "--quiet", *extra]


def _full_disk(monkeypatch, module: str, name: str) -> None:
    import importlib

    def full(*a, **kw):
        raise OSError(errno.ENOSPC, "No space left on device")

    owner = importlib.import_module(module)
    *path, name = name.split(".")
    for attr in path:  # a method: Class.method
        owner = getattr(owner, attr)
    monkeypatch.setattr(owner, name, full)


def onnx_folder(d: Path, opset: int = 18, **export) -> Path:
    """A model folder as export-onnx writes it (lite, the shipped weights, ``export``'s settings) whose two graphs
    are stand-ins (an identity stamped with ``opset``): enough for every check made before onnxruntime runs."""
    import json

    import onnx
    from onnx import TensorProto, helper

    from mvsformerpp.io.onnx_model import GRAPH_FILES
    from mvsformerpp.models.presets import get_config
    from mvsformerpp.models.weights import weights_for
    from mvsformerpp.pipelines.export_onnx_config import OnnxExportConfig
    from mvsformerpp.pipelines.onnx_record import model_record
    from mvsformerpp.utils.files import file_sha256

    folder = d / "model"
    folder.mkdir()
    graphs = {}
    for name, file in GRAPH_FILES.items():
        io_ = [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1]) for n in ("x", "y")]
        graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], name, io_[:1], io_[1:])
        onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)]), folder / file)
        graphs[name] = {"file": file, "sha256": file_sha256(folder / file)}
    config = OnnxExportConfig(**export)
    weights = weights_for(config.preset, config.checkpoint, config.seed)
    (folder / "model.json").write_text(json.dumps(model_record(config, get_config(config.preset), weights, graphs)))
    return folder


def _changed_onnx_graph(d: Path) -> list[str]:
    model = onnx_folder(d, num_views=3)
    with open(model / "view_set.onnx", "ab") as f:
        f.write(b"\0")
    return recon(d, "--backend", "onnxruntime", "--onnx-model", str(model))


# ------------------------------------------------------------------------------------------ cases
def _mismatched_image(d: Path) -> list[str]:
    from PIL import Image

    s = scene(d)
    Image.new("RGB", (100, 100)).save(s / "images" / "00000001.png")
    return recon(d, src=s)


def _duplicate_sources(d: Path) -> list[str]:
    s = scene(d)
    (s / "pair.txt").write_text("3\n0\n2 1 1.0 1 0.5\n1\n2 0 1.0 2 0.5\n2\n2 0 1.0 1 0.5\n")
    return recon(d, src=s)


def _wrong_size_depth(d: Path) -> list[str]:
    from mvsformerpp.io.pfm import write_pfm

    s = fused_folder(d)
    write_pfm(s / "depth_est" / "00000001.pfm", np.ones((50, 50), np.float32))
    return ["fuse", str(s), "--quiet"]


def _wrong_size_confidence(d: Path) -> list[str]:
    from mvsformerpp.io.pfm import write_pfm

    s = fused_folder(d)
    write_pfm(s / "confidence" / "00000001.pfm", np.ones((32, 48), np.float32))
    return ["fuse", str(s), "--quiet"]


def _singular_alignment(d: Path) -> list[str]:
    (d / "T.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 0 0\n0 0 0 1\n")
    return ["evaluate", "tnt", str(cloud(d / "p.ply")), str(cloud(d / "g.ply", seed=1)), "--threshold", "0.1",
            "--alignment", str(d / "T.txt")]


def _crafted_checkpoint(d: Path) -> list[str]:
    import pickle

    class Call:
        def __reduce__(self):
            return shutil.rmtree, (str(d / "scene"),)

    (d / "evil.pth").write_bytes(pickle.dumps(Call(), protocol=2))
    return recon(d, "--checkpoint", str(d / "evil.pth"))


def _depth_lines(d: Path, line: str) -> Path:
    s = scene(d)
    for p in (s / "cams").glob("*_cam.txt"):
        lines = p.read_text().strip().splitlines()
        lines[-1] = line
        p.write_text("\n".join(lines) + "\n")
    return s


def _pair(d: Path, text: str) -> Path:
    s = scene(d)
    (s / "pair.txt").write_text(text)
    return s


def _cam_token(d: Path, line: int, token: str) -> Path:
    """Replace the first number on ``line`` of view 0's cam file."""
    s = scene(d)
    p = s / "cams" / "00000000_cam.txt"
    lines = p.read_text().splitlines()
    lines[line] = " ".join([token] + lines[line].split()[1:])
    p.write_text("\n".join(lines) + "\n")
    return s


def _non_empty_synth(d: Path) -> list[str]:
    (d / "mine").mkdir()
    (d / "mine" / "notes.txt").write_text("keep")
    return ["synth", str(d / "mine")]


def _file(d: Path, name: str, data: bytes = b"x") -> Path:
    (d / name).write_bytes(data)
    return d / name


def _duplicate_cam(d: Path) -> list[str]:
    s = scene(d)
    shutil.copy(s / "cams" / "00000001_cam.txt", s / "cams" / "1_cam.txt")
    return recon(d, src=s)


def _camera(d: Path, change: Callable[[object], None]) -> list[str]:
    """reconstruct of a scene whose view 1 has its camera changed by ``change`` (of an MVSNetCam)."""
    from mvsformerpp.io.mvsnet import read_cam, write_cam

    s = scene(d)
    cam = read_cam(s / "cams" / "00000001_cam.txt")
    change(cam)
    write_cam(s / "cams" / "00000001_cam.txt", cam)
    return recon(d, src=s)


def _focal(value: float) -> Callable[[Path], list[str]]:
    def change(cam) -> None:
        cam.K[0, 0] = cam.K[1, 1] = value

    return lambda d: _camera(d, change)


def _translation(d: Path) -> list[str]:
    def change(cam) -> None:
        cam.extrinsic[0, 3] = 1e30

    return _camera(d, change)


def _images_without_points_line(d: Path) -> list[str]:
    project = colmap_project(d)
    path = project / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
    del lines[first + 1]  # the first image's 2-D points line
    path.write_text("\n".join(lines) + "\n")
    return recon(d, src=project)


def _black_masks(d: Path) -> list[str]:
    from PIL import Image

    s = scene(d)
    (d / "masks").mkdir()
    for p in sorted((s / "images").iterdir()):
        with Image.open(p) as im:
            Image.new("L", im.size, 0).save(d / "masks" / f"{p.stem}.png")
    return recon(d, "--mask-dir", str(d / "masks"), src=s)


def _ply_count(d: Path, count: str) -> Path:
    path = cloud(d / "p.ply")
    raw = path.read_bytes()
    line = next(x for x in raw[:raw.index(b"end_header")].split(b"\n") if x.startswith(b"element vertex"))
    path.write_bytes(raw.replace(line, b"element vertex " + count.encode()))
    return path


def _export_into_parent(d: Path) -> list[str]:
    out = fused_folder(d)
    for sub in ("images", "sparse", "stereo"):
        (d / sub).mkdir(exist_ok=True)
    return ["export", str(out), "--to", "colmap", str(d), "--overwrite", "--quiet"]


def _export_over_user_folder(d: Path) -> list[str]:
    out = fused_folder(d)
    (d / "mine").mkdir()
    (d / "mine" / "notes.txt").write_text("keep")
    return ["export", str(out), "--to", "colmap", str(d / "mine"), "--overwrite", "--quiet"]


def _recipe_in_run_folder(d: Path) -> list[str]:
    (d / "exp").mkdir()
    (d / "exp" / "config.yaml").write_text("# my recipe\nrecipe: synthetic\nmax_steps: 1\n")
    return ["train", str(d / "exp" / "config.yaml"), "-o", str(d / "exp")]


def _short_par_line(d: Path) -> list[str]:
    (d / "m").mkdir()
    (d / "m" / "x_par.txt").write_text("1\na.png " + " ".join(["1"] * 20) + "\n")
    return recon(d, src=d / "m")


def _error_ply_over_input(d: Path, which: str) -> list[str]:
    pred = cloud(d / ("c_precision.ply" if which == "prediction" else "p.ply"))
    gt = cloud(d / ("c_recall.ply" if which == "ground truth" else "g.ply"), seed=1)
    return ["evaluate", "cloud", str(pred), str(gt), "--threshold", "0.1", "--error-ply", str(d / "c.ply")]


def _tnt(d: Path, out: Path, scene_name: str = "Barn", *extra: str) -> list[str]:
    from mvsformerpp.evaluation.tnt_submission import write_log

    write_log(d / "cams.log", np.eye(4)[None].repeat(2, 0))
    return ["evaluate", "tnt-submit", str(out), scene_name, str(cloud(d / "p.ply")), str(d / "cams.log"), *extra]


def _export_over_recon_input(d: Path) -> list[str]:
    run = reconstruction(d)
    quietly("export", str(run), "--to", "colmap", str(d / "ws"), "--quiet")
    edit(run / "config.json", str(d / "input"), str(d / "ws"))  # as `reconstruct ws -o run` records it
    return ["export", str(run), "--to", "colmap", str(d / "ws"), "--overwrite", "--quiet"]


def _export_onto_symlink(d: Path) -> list[str]:
    run = fused_folder(d)
    (d / "elsewhere").mkdir()
    (d / "ws").symlink_to(d / "elsewhere")
    return ["export", str(run), "--to", "colmap", str(d / "ws"), "--overwrite", "--quiet"]


def _coincident_cloud(d: Path) -> list[str]:
    from mvsformerpp.io.ply import write_ply

    run = fused_folder(d)
    write_ply(run / "fused.ply", np.zeros((500, 3)), normals=np.tile([0.0, 0.0, 1.0], (500, 1)))
    return ["mesh", str(run), "-o", str(d / "m.ply"), "--method", "poisson", "--quiet"]


def _binary_recipe(d: Path) -> list[str]:
    (d / "recipe.yaml").write_bytes(bytes(range(256)))
    return ["train", str(d / "recipe.yaml"), "-o", str(d / "run")]


def _black_depth_masks(d: Path) -> list[str]:
    from PIL import Image

    s = scene(d)
    (d / "masks").mkdir()
    for p in sorted((s / "depth_gt").glob("*.pfm")):
        Image.new("L", (96, 64), 0).save(d / "masks" / f"{p.stem}.png")
    return ["evaluate", "depth", str(s / "depth_gt"), str(s / "depth_gt"), "--mask-dir", str(d / "masks")]


def _read_only_place(monkeypatch, suffix: str) -> None:
    """Creating files whose name ends with ``suffix`` fails as on a read-only file system."""
    import tempfile

    def refuse(name: str):
        raise OSError(errno.EROFS, "Read-only file system", name)

    real_mkstemp, real_open = tempfile.mkstemp, os.open
    monkeypatch.setattr(tempfile, "mkstemp", lambda *a, **k: refuse(os.path.join(k.get("dir", "."), "tmp"))
                        if str(k.get("suffix", "")).endswith(suffix) else real_mkstemp(*a, **k))
    monkeypatch.setattr(os, "open", lambda path, *a, **k: refuse(path) if str(path).endswith(suffix)
                        else real_open(path, *a, **k))


def mesh(*flags: str, fused: bool = False) -> Callable[[Path], list[str]]:
    """A case's command: ``mesh OUT -o DIR/m.ply FLAGS`` on depth maps, or with ``fused`` on a reconstruction with its
    fused cloud."""
    return lambda d: ["mesh", str(reconstruction(d) if fused else fused_folder(d)), "-o", str(d / "m.ply"), *flags,
                      "--quiet"]


def into_scene(command: str, *where: str) -> Callable[[Path], list[str]]:
    """A case's command: ``COMMAND SCENE -o SCENE/WHERE...`` on a scene folder with depth maps (fuse, mesh, report)."""
    def build(d: Path) -> list[str]:
        s = fused_folder(d)
        return [command, str(s), "-o", str(s.joinpath(*where)), *(["--quiet"] if command != "report" else [])]

    return build


def _photo_folder(d: Path, name: str = "photos", size: int = 96, licence: str | None = "CC0-1.0",
                  junk: bool = False) -> Path:
    """A folder of two textured photos (``size`` px) with a source.json (``licence`` None: without one)."""
    from PIL import Image

    folder = d / name
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):
        Image.fromarray(rng.integers(0, 256, (size, size, 3), dtype=np.uint8)).save(folder / f"p{k}.png")
    if junk:
        (folder / "p1.png").write_bytes(b"not an image")
    if licence is not None:
        (folder / "source.json").write_text(json.dumps({"licence": licence, "source": "test photos"}))
    return folder


def _llff(d: Path, drop_photo: bool = False) -> Path:
    """An LLFF capture of 3 views of 64x48 (poses_bounds.npy + images/); ``drop_photo``: one photo missing."""
    from PIL import Image

    folder = d / "capture"
    (folder / "images").mkdir(parents=True)
    rows = []
    for i in range(3):
        m = np.zeros((3, 5))
        m[:, :3] = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]  # (down, right, back) of a camera looking along +z
        m[:, 3] = [0.1 * i, 0, 0]
        m[:, 4] = [48, 64, 60]
        rows.append(np.concatenate([m.ravel(), [1.0, 5.0]]))
        if not (drop_photo and i == 2):
            Image.new("RGB", (64, 48), (90, 90, 90)).save(folder / "images" / f"{i:03d}.png")
    np.save(folder / "poses_bounds.npy", np.array(rows))
    return folder


def train_set(*values: str) -> Callable[[Path], list[str]]:
    """A case's command: ``train synthetic -o DIR/run --set VALUE ...``."""
    return lambda d: ["train", "synthetic", "-o", str(d / "run"), *[a for v in values for a in ("--set", v)]]


_TINY_TRAIN = ["--max-steps", "1", "--batch-size", "1", "--height", "32", "--width", "32", "--views", "2", "--set",
               "val_samples=1", "--set", "synthetic_views_per_scene=2", "--set", "progress=false", "--set",
               "tensorboard=false", "--set", "val_every=0"]


CASES: list[Case] = [
    # reconstruct: the input
    Case("recon-missing-input", "INPUT does not exist", lambda d: recon(d, src=d / "nowhere"), "no such file"),
    Case("recon-empty-folder", "INPUT is an empty folder", lambda d: recon(d, src=(d / "e").mkdir() or d / "e"),
         "no scene found"),
    Case("recon-no-cams", "an MVSNet folder whose cams/ is missing",
         lambda d: recon(d, src=(lambda s: shutil.rmtree(s / "cams") or s)(scene(d))), "cams"),
    Case("recon-colmap-no-points3d", "a COLMAP model without points3D.txt",
         lambda d: recon(d, src=colmap_project(d, points=False)), "points3D"),
    Case("recon-colmap-empty-points3d", "a COLMAP model whose points3D.txt holds no point",
         lambda d: recon(d, src=colmap_project(d, empty_points=True)), "no 3-D point|depth range"),
    Case("recon-missing-image", "a camera whose photo is missing",
         lambda d: recon(d, src=(lambda s: (s / "images" / "00000001.png").unlink() or s)(scene(d))), "no image"),
    Case("recon-corrupt-image", "a photo that is not an image",
         lambda d: recon(d, src=(lambda s: _file(s / "images", "00000001.png", b"junk") and s)(scene(d))),
         "image"),
    Case("recon-image-camera-mismatch", "a 100x100 photo for a 96x64 camera", _mismatched_image, "100x100"),
    Case("recon-duplicate-sources", "pair.txt lists a source view twice", _duplicate_sources, "twice"),
    Case("recon-pair-out-of-range", "pair.txt names a view that does not exist",
         lambda d: recon(d, src=_pair(d, "3\n0\n2 7 1.0 1 0.5\n1\n2 0 1.0 2 0.5\n2\n2 0 1.0 1 0.5\n")), "7"),
    Case("recon-cam-duplicate", "two cam files for one view (`1_cam.txt` beside `00000001_cam.txt`)", _duplicate_cam,
         "two cam files for view 1"),
    Case("recon-focal-huge", "a focal length of 1e30 pixels", _focal(1e30), "field of view"),
    Case("recon-colmap-missing-points-line", "a COLMAP images.txt missing an image's 2-D points line",
         _images_without_points_line, "2-D points of image"),
    Case("recon-masks-all-black", "--mask-dir whose masks are all black", _black_masks,
         "mark no pixel of any view as object"),
    Case("recon-cam-nan", "a cam file with a NaN in its rotation",
         lambda d: recon(d, src=_cam_token(d, 1, "nan")), "non-finite"),
    Case("recon-depth-line-zero-interval", "a depth line `MIN 0` (zero interval)",
         lambda d: recon(d, src=_depth_lines(d, "5 0")), "depth range"),
    Case("recon-depth-line-negative", "a depth line with a negative MIN",
         lambda d: recon(d, src=_depth_lines(d, "-5 0.1 192 14")), "depth"),
    Case("recon-one-view", "--max-images 1", lambda d: recon(d, "--max-images", "1"), "at least 2"),
    Case("recon-conf-out-of-range", "--conf 1.5", lambda d: recon(d, "--conf", "1.5"), "--conf"),
    # reconstruct: the output folder
    Case("recon-out-is-input", "-o is the input folder", lambda d: recon(d, out=d / "scene"), "is the input"),
    Case("recon-out-inside-input", "-o lies inside the input folder", lambda d: recon(d, out=d / "scene" / "o"),
         "inside the input"),
    Case("recon-out-contains-input", "-o contains the input folder", lambda d: recon(d, out=d), "contains the input"),
    Case("recon-out-other-scene", "-o is another scene's folder",
         lambda d: recon(d, out=scene(d, "other")), "not written by mvsformerpp reconstruct"),
    Case("recon-out-under-file", "-o lies under a file", lambda d: recon(d, out=_file(d, "f") / "out"),
         "which is a file, not a folder"),
    Case("recon-out-read-only", "-o on a read-only file system", lambda d: recon(d, out=d / "ro"),
         "Read-only file system",
         patch=lambda mp: mp.setattr(Path, "mkdir", lambda *a, **k: (_ for _ in ()).throw(
             OSError(errno.EROFS, "Read-only file system")))),
    # reconstruct: settings
    Case("recon-views-1", "--views 1", lambda d: recon(d, "--views", "1"), "--views"),
    Case("recon-max-size-10", "--max-size 10", lambda d: recon(d, "--max-size", "10"), "--max-size"),
    Case("recon-depth-range-empty", "--depth-range 0.6 0.5", lambda d: recon(d, "--depth-range", "0.6", "0.5"),
         "0 < min < max"),
    Case("recon-depth-range-negative", "--depth-range -1 2", lambda d: recon(d, "--depth-range", "-1", "2"),
         "0 < min < max"),
    Case("recon-cache-negative", "--cache-mb -1", lambda d: recon(d, "--cache-mb", "-1"), "--cache-mb"),
    Case("recon-memory-zero", "--memory-gb 0", lambda d: recon(d, "--memory-gb", "0"), "--memory-gb"),
    Case("recon-memory-nan", "--memory-gb nan", lambda d: recon(d, "--memory-gb", "nan"), "--memory-gb"),
    Case("recon-memory-inf", "--memory-gb inf", lambda d: recon(d, "--memory-gb", "inf"), "--memory-gb"),
    Case("recon-cvt-shifts-five", "--cvt-shifts 5",
         lambda d: recon(d, "--cvt-shifts", "5"), "--cvt-shifts"),
    Case("recon-min-parallax-negative", "--min-parallax -1",
         lambda d: recon(d, "--min-parallax", "-1"), "--min-parallax"),
    Case("recon-min-parallax-nan", "--min-parallax nan",
         lambda d: recon(d, "--min-parallax", "nan"), "--min-parallax"),
    Case("recon-temperatures-zero", "--temperatures 0 0 0 0",
         lambda d: recon(d, "--temperatures", "0", "0", "0", "0"), "--temperatures"),
    Case("recon-temperatures-nan", "--temperatures nan 5 5 1",
         lambda d: recon(d, "--temperatures", "nan", "5", "5", "1"), "--temperatures"),
    Case("recon-temperatures-negative", "--temperatures -5 5 5 1",
         lambda d: recon(d, "--temperatures", "-5", "5", "5", "1"), "--temperatures"),
    Case("recon-num-depth-zero", "--num-depth 0", lambda d: recon(d, "--num-depth", "0"), "--num-depth"),
    Case("recon-interval-scale-inf", "--interval-scale inf", lambda d: recon(d, "--interval-scale", "inf"),
         "--interval-scale"),
    Case("recon-device-cuda", "--device cuda on a machine without CUDA", lambda d: recon(d, "--device", "cuda"),
         "CUDA is not available", needs_no_cuda=True),
    Case("recon-device-meta", "--device meta", lambda d: recon(d, "--device", "meta"), "meta"),
    Case("recon-device-unknown", "--device banana", lambda d: recon(d, "--device", "banana"), "banana"),
    Case("recon-checkpoint-missing", "--checkpoint that does not exist",
         lambda d: recon(d, "--checkpoint", str(d / "none.pth")), "not found"),
    Case("recon-checkpoint-junk", "--checkpoint that is not a checkpoint",
         lambda d: recon(d, "--checkpoint", str(_file(d, "junk.pth", b"not a checkpoint"))), "cannot read"),
    Case("recon-checkpoint-code", "--checkpoint holding a pickled function call", _crafted_checkpoint,
         "refusing to load"),
    # fuse
    Case("fuse-no-depth", "a scene folder without depth maps", lambda d: ["fuse", str(scene(d)), "--quiet"],
         "no depth map"),
    Case("fuse-wrong-size-depth", "a 50x50 depth map for a 96x64 view", _wrong_size_depth, "depth map"),
    Case("fuse-wrong-size-confidence", "a confidence map of another size than its depth map",
         _wrong_size_confidence, "confidence map"),
    Case("fuse-conf-nan", "--conf nan", lambda d: ["fuse", str(fused_folder(d)), "--conf", "nan"], "--conf"),
    Case("fuse-disp-negative", "--disp -1", lambda d: ["fuse", str(fused_folder(d)), "--disp", "-1"], "--disp"),
    Case("fuse-num-consistent-negative", "--num-consistent -1",
         lambda d: ["fuse", str(fused_folder(d)), "--num-consistent", "-1"], "--num-consistent"),
    Case("fuse-num-src-zero", "--num-src-views 0", lambda d: ["fuse", str(fused_folder(d)), "--num-src-views", "0"],
         "--num-src-views"),
    Case("fuse-memory-nan", "fuse --memory-gb nan", lambda d: ["fuse", str(fused_folder(d)), "--memory-gb", "nan"],
         "--memory-gb"),
    Case("fuse-memory-inf", "fuse --memory-gb inf", lambda d: ["fuse", str(fused_folder(d)), "--memory-gb", "inf"],
         "--memory-gb"),
    Case("fuse-device-cuda", "fuse --device cuda without CUDA",
         lambda d: ["fuse", str(fused_folder(d)), "--device", "cuda"], "CUDA is not available", needs_no_cuda=True),
    Case("fuse-device-meta", "fuse --device meta", lambda d: ["fuse", str(fused_folder(d)), "--device", "meta"],
         "meta"),
    Case("fuse-disk-full", "the disk fills up while fuse writes the cloud",
         lambda d: ["fuse", str(fused_folder(d)), "--quiet"], "No space left",
         patch=lambda mp: _full_disk(mp, "mvsformerpp.io.ply", "PlyStreamWriter.write")),
    Case("fuse-output-is-photo", "fuse -o pointing at an input photo", into_scene("fuse", "images", "00000000.png"),
         "not a PLY"),
    Case("mesh-output-is-photo", "mesh -o pointing at an input photo", into_scene("mesh", "images", "00000000.png"),
         "not a PLY mesh"),
    Case("report-output-is-photo", "report -o pointing at an input photo",
         into_scene("report", "images", "00000000.png"), "not an HTML report"),
    Case("eval-json-is-photo", "evaluate --json pointing at a photo",
         lambda d: (lambda s: ["evaluate", "cloud", str(s / "fused.ply"), str(s / "fused.ply"), "--threshold", "1",
                               "--json", str(s / "images" / "00000000.png")])(fused_folder(d)),
         "not an evaluation JSON"),
    Case("mesh-disk-full", "the disk fills up while mesh writes the mesh",
         lambda d: ["mesh", str(fused_folder(d)), "-o", str(d / "m.ply"), "--quiet"], r"m\.ply.*No space left",
         patch=lambda mp: _full_disk(mp, "mvsformerpp.utils.atomic", "os.fsync")),
    Case("export-overwrite-parent", "export OUT --to colmap PARENT --overwrite, PARENT holding OUT",
         _export_into_parent, "contains the input DIR/scene"),
    Case("export-overwrite-user-folder", "export --overwrite onto a folder of the user's own files",
         _export_over_user_folder, "replaces only an empty folder or one that mvsformerpp export wrote"),
    Case("view-host-unknown", "view --host 999.1.1.1",
         lambda d: ["view", str(fused_folder(d)), "--host", "999.1.1.1"], "--host"),
    # evaluate
    Case("eval-ply-count-negative", "a PLY whose header announces -1 vertices",
         lambda d: ["evaluate", "cloud", str(_ply_count(d, "-1")), str(cloud(d / "g.ply")), "--threshold", "1"],
         "count"),
    Case("eval-ply-count-short", "a PLY whose header announces fewer vertices than it holds",
         lambda d: ["evaluate", "cloud", str(_ply_count(d, "7")), str(cloud(d / "g.ply")), "--threshold", "1"],
         "announces 7 vertices but the file holds 200"),
    Case("eval-cloud-threshold-zero", "evaluate cloud --threshold 0",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "0"],
         "--threshold"),
    Case("eval-cloud-threshold-negative", "evaluate cloud --threshold -1",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "-1"],
         "--threshold"),
    Case("eval-cloud-threshold-nan", "evaluate cloud --threshold nan",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "nan"],
         "--threshold"),
    Case("eval-cloud-missing", "evaluate cloud with a missing PLY",
         lambda d: ["evaluate", "cloud", str(d / "none.ply"), str(cloud(d / "g.ply")), "--threshold", "1"],
         "none.ply"),
    Case("eval-cloud-not-ply", "evaluate cloud with a file that is not a PLY",
         lambda d: ["evaluate", "cloud", str(_file(d, "p.ply", b"hello")), str(cloud(d / "g.ply")), "--threshold",
                    "1"], "PLY"),
    Case("eval-cloud-error-ply-disk-full", "the disk fills up while evaluate writes --error-ply",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "0.1",
                    "--error-ply", str(d / "err.ply")], "No space left",
         patch=lambda mp: _full_disk(mp, "mvsformerpp.evaluation.visualize", "write_ply")),
    Case("eval-depth-threshold-zero", "evaluate depth --thresholds 0",
         lambda d: ["evaluate", "depth", str(d), str(d), "--thresholds", "0"], "--thresholds"),
    Case("eval-depth-interval-negative", "evaluate depth --interval -1",
         lambda d: ["evaluate", "depth", str(d), str(d), "--interval", "-1"], "--interval"),
    Case("eval-depth-inlier-ratio", "evaluate depth --inlier-ratio 1",
         lambda d: ["evaluate", "depth", str(d), str(d), "--inlier-ratio", "1"], "--inlier-ratio"),
    Case("eval-eth3d-tolerance-zero", "evaluate eth3d --tolerances 0",
         lambda d: ["evaluate", "eth3d", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--tolerances", "0"],
         "--tolerances"),
    Case("eval-tnt-singular-alignment", "evaluate tnt with a singular alignment matrix", _singular_alignment,
         "singular|invertible"),
    # synth and info
    Case("synth-non-empty", "synth into a folder holding other files", _non_empty_synth, "not empty"),
    Case("synth-huge", "synth --height 100000 --width 100000",
         lambda d: ["synth", str(d / "s"), "--height", "100000", "--width", "100000"], "--height"),
    Case("synth-views-1", "synth --views 1", lambda d: ["synth", str(d / "s"), "--views", "1"], "--views"),
    Case("synth-detail-classic", "synth --detail 0.5 with the classic style",
         lambda d: ["synth", str(d / "s"), "--detail", "0.5"], "--detail"),
    Case("synth-layout-classic", "synth --layout room with the classic style",
         lambda d: ["synth", str(d / "s"), "--layout", "room"], "--layout"),
    Case("synth-plain-walls-heldout", "synth --style heldout --plain-walls 0.5 (no walls in that style)",
         lambda d: ["synth", str(d / "s"), "--style", "heldout", "--plain-walls", "0.5"], "--plain-walls"),
    Case("synth-plain-walls-2", "synth --style train --plain-walls 2 (not a probability)",
         lambda d: ["synth", str(d / "s"), "--style", "train", "--plain-walls", "2"], "--plain-walls"),
    Case("synth-detail-nan", "synth --style train --detail nan",
         lambda d: ["synth", str(d / "s"), "--style", "train", "--detail", "nan"], "--detail"),
    Case("synth-objects-huge", "synth --objects 1000000000 (hung rendering)",
         lambda d: ["synth", str(d / "s"), "--objects", "1000000000"], "--objects"),
    Case("synth-seed-negative", "synth --seed -1", lambda d: ["synth", str(d / "s"), "--seed", "-1"], "--seed"),
    # mesh
    Case("mesh-trim-150", "mesh --method poisson --trim 150",
         lambda d: ["mesh", str(fused_folder(d)), "-o", str(d / "m.ply"), "--method", "poisson", "--trim", "150"],
         "--trim"),
    Case("mesh-max-distance-negative", "mesh --method poisson --max-distance -1",
         lambda d: ["mesh", str(fused_folder(d)), "-o", str(d / "m.ply"), "--method", "poisson", "--max-distance",
                    "-1"], "--max-distance"),
    Case("mesh-voxel-nan", "mesh --voxel nan", lambda d: ["mesh", str(fused_folder(d)), "-o", str(d / "m.ply"),
                                                          "--voxel", "nan"], "--voxel"),
    Case("mesh-depth-100", "mesh --method poisson --depth 100",
         lambda d: ["mesh", str(fused_folder(d)), "-o", str(d / "m.ply"), "--method", "poisson", "--depth", "100"],
         "--depth"),
    Case("mesh-min-conf-2", "mesh --min-conf 2", lambda d: ["mesh", str(fused_folder(d)), "-o", str(d / "m.ply"),
                                                             "--min-conf", "2"], "--min-conf"),
    # train
    Case("train-lr-negative", "train --set lr=-1",
         train_set("lr=-1"), "lr"),
    Case("train-lr-nan", "train --set lr=.nan",
         train_set("lr=.nan"), "lr"),
    Case("train-num-depth-zero", "train --set num_depth=0",
         train_set("num_depth=0"), "num_depth"),
    Case("train-scenes-negative", "train --set synthetic_train_scenes=-1",
         train_set("synthetic_train_scenes=-1"),
         "synthetic_train_scenes"),
    Case("train-scenes-huge", "train --set synthetic_train_scenes=1000000000 (hung ordering an epoch)",
         train_set("synthetic_train_scenes=1000000000"),
         "at most"),
    Case("train-workers-huge", "train --set num_workers=1000000000 (hung starting processes)",
         train_set("num_workers=1000000000"), "num_workers"),
    Case("train-warmup-negative", "train --set warmup_steps=-5",
         train_set("warmup_steps=-5"), "warmup_steps"),
    Case("train-scene-batches-split", "train --set synthetic_scene_batches=true with a batch that splits a scene",
         train_set("synthetic_scene_batches=true", "batch_size=4"),
         "synthetic_scene_batches"),
    Case("train-placements-both", "train --set cvt_train_shifts=true --set cvt_random_placement=true",
         train_set("cvt_train_shifts=true", "cvt_random_placement=true"), "set at most one of them true"),
    Case("train-stages-five", "train --set train_stages=5",
         train_set("train_stages=5"), "train_stages"),
    Case("train-trainable-typo", "train --set trainable=[fusion.0] (no parameter has that name)",
         train_set("trainable=[fusion.0]", "max_steps=1"), "names no parameter"),
    Case("train-source-os-system", "train --set synthetic_source=os:system (not a scene generator)",
         train_set("synthetic_source=os:system"),
         "not a scene generator"),
    Case("train-parallax-outside", "a recipe whose views fall outside its declared parallax_range",
         lambda d: ["train", "synthetic", "-o", str(d / "run"), "--set", "parallax_range=[30, 60]",
                    "--set", "parallax_samples=2", "--height", "64", "--width", "96"], "parallax_range"),
    Case("train-overlap-below", "a recipe whose source views see less of the reference than its min_overlap",
         lambda d: ["train", "synthetic", "-o", str(d / "run"), "--set", "min_overlap=0.999",
                    "--set", "parallax_samples=2", "--height", "64", "--width", "96"], "min_overlap"),
    Case("train-output-holds-recipe", "train exp/config.yaml -o exp (the run folder holds the recipe)",
         _recipe_in_run_folder, "holds the input"),
    Case("train-output-user-folder", "train -o a folder of the user's own files",
         lambda d: (lambda f: ["train", "synthetic", "-o", str(f)])(_file(d, "notes.txt").parent), "train"),
    Case("train-first-save-disk-full", "the disk fills up at training's first checkpoint",
         lambda d: ["train", "synthetic", "-o", str(d / "run"), *_TINY_TRAIN], "without --resume",
         patch=lambda mp: _full_disk(mp, "mvsformerpp.training.checkpoints", "atomic_write_bytes")),
    Case("export-disk-full", "the disk fills up while export writes the workspace",
         lambda d: ["export", str(fused_folder(d)), "--to", "colmap", str(d / "ws"), "--quiet"], "No space left",
         patch=lambda mp: _full_disk(mp, "mvsformerpp.utils.atomic", "os.fsync")),
    Case("recon-par-short-line", "a Middlebury par line with 20 numbers instead of 21", _short_par_line,
         "21 numbers"),
    Case("recon-llff-photo-missing", "an LLFF capture whose poses_bounds.npy holds more cameras than images/ photos",
         lambda d: recon(d, src=_llff(d, drop_photo=True)), "do not fit the images"),
    # textures and real photos in training
    Case("textures-empty-folder", "textures on an empty folder",
         lambda d: ["textures", str((d / "e").mkdir() or d / "e"), "-o", str(d / "lib")], "no photos"),
    Case("textures-unreadable-photo", "textures on a folder holding a file that is not an image",
         lambda d: ["textures", str(_photo_folder(d, junk=True)), "-o", str(d / "lib")], "not a readable image"),
    Case("textures-too-small", "textures on photos of 20x20 pixels",
         lambda d: ["textures", str(_photo_folder(d, size=20)), "-o", str(d / "lib")], "too small to crop"),
    Case("textures-no-licence", "textures on photos without a source.json",
         lambda d: ["textures", str(_photo_folder(d, licence=None)), "-o", str(d / "lib")], "no source.json"),
    Case("textures-non-commercial", "textures on photos under CC-BY-NC-4.0",
         lambda d: ["textures", str(_photo_folder(d, licence="CC-BY-NC-4.0")), "-o", str(d / "lib")],
         "does not allow"),
    Case("train-textures-missing", "train with a texture library that does not exist",
         lambda d: train_set(f"synthetic_options={{style: train, textures: {d / 'nowhere'}}}")(d),
         "texture library not found"),
    Case("train-real-photo-missing", "train with a real scene whose cameras outnumber its photos",
         lambda d: train_set(f"real_scenes=[{_llff(d, drop_photo=True)}]", "self_supervised_weight=1")(d),
         "do not fit the images"),
    Case("train-real-no-loss", "train with real scenes but neither teacher labels nor self-supervision",
         lambda d: train_set(f"real_scenes=[{_llff(d)}]")(d), "real_labels"),
    Case("info-missing", "info on a path that does not exist", lambda d: ["info", str(d / "nowhere")],
         "no such file"),
    Case("info-depth-range-reversed", "info --depth-range 5 1",
         lambda d: ["info", str(scene(d)), "--depth-range", "5", "1"], "0 < min < max"),
    # the output guard, round 4: data that used to be lost
    Case("mesh-over-fused-cloud", "mesh OUT -o OUT/fused.ply (the reconstruction's own cloud)",
         lambda d: (lambda r: ["mesh", str(r), "-o", str(r / "fused.ply"), "--quiet"])(reconstruction(d)),
         "is the input .*fused.ply"),
    Case("mesh-poisson-over-fused-cloud", "mesh OUT -o OUT/fused.ply --method poisson",
         lambda d: (lambda r: ["mesh", str(r), "-o", str(r / "fused.ply"), "--method", "poisson", "--quiet"])(
             reconstruction(d)), "is the input .*fused.ply"),
    Case("eval-error-ply-over-prediction", "evaluate cloud c_precision.ply GT --error-ply c.ply",
         lambda d: _error_ply_over_input(d, "prediction"), "c_precision.ply: the output is the input"),
    Case("eval-error-ply-over-gt", "evaluate cloud PRED c_recall.ply --error-ply c.ply",
         lambda d: _error_ply_over_input(d, "ground truth"), "c_recall.ply: the output is the input"),
    Case("eval-plot-over-photo", "evaluate cloud --plot SCENE/images/00000001.png (a photo)",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "1",
                    "--plot", str(scene(d) / "images" / "00000001.png")], "did not write as a PNG plot"),
    Case("eval-json-in-package", "evaluate --json onto the shipped weights' record in the installed package",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "1",
                    "--json", str(package_file("assets", "weights", "default.json"))], "installed mvsformerpp package"),
    Case("eval-plot-in-package", "evaluate --plot onto a photo of the bundled temple",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "1",
                    "--plot", str(package_file("assets", "templeSparseRing", "templeSR0001.png"))],
         "installed mvsformerpp package"),
    Case("eval-json-over-run-config", "evaluate --json OUT/config.json (a reconstruction's record)",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "1",
                    "--json", str(reconstruction(d) / "config.json")], "did not write as an evaluation JSON"),
    Case("eval-depth-json-over-scene-file", "evaluate depth --json SCENE/scene.json (a synthetic scene's record)",
         lambda d: (lambda s: ["evaluate", "depth", str(s / "depth_gt"), str(s / "depth_gt"), "--json",
                               str(s / "scene.json")])(scene(d)), "did not write as an evaluation JSON"),
    Case("tnt-scene-escapes", "evaluate tnt-submit with the scene name ../../escaped",
         lambda d: _tnt(d, d / "sub", "../../escaped"), "not a Tanks-and-Temples scene"),
    Case("tnt-scene-gt-surface", "evaluate tnt-submit SCENE gt_surface ... --overwrite (SCENE/gt_surface.ply)",
         lambda d: _tnt(d, scene(d), "gt_surface", "--overwrite"), "not a Tanks-and-Temples scene"),
    Case("tnt-scene-empty", "evaluate tnt-submit with an empty scene name",
         lambda d: _tnt(d, d / "sub", ""), "'' is not a Tanks-and-Temples scene"),
    Case("tnt-scene-unknown", "evaluate tnt-submit with the scene name barn (the benchmark's is Barn)",
         lambda d: _tnt(d, d / "sub", "barn"), "did you mean Barn"),
    Case("tnt-into-reconstruction", "evaluate tnt-submit OUT Barn=OUT (into the reconstruction itself)",
         lambda d: (lambda r: ["evaluate", "tnt-submit", str(r), f"Barn={r}"])(reconstruction(d)),
         "is the input"),
    Case("tnt-into-user-folder", "evaluate tnt-submit into a folder of the user's own files",
         lambda d: _tnt(d, (d / "mine").mkdir() or _file(d / "mine", "notes.txt").parent),
         "not written by mvsformerpp tnt-submit"),
    Case("export-over-recon-input", "reconstruct WS -o OUT; export OUT --to colmap WS --overwrite",
         _export_over_recon_input, "the output folder is the input DIR/ws"),
    Case("export-onto-symlink", "export --overwrite onto a symbolic link to a folder", _export_onto_symlink,
         "symbolic link"),
    # the output guard, round 4: tracebacks and hangs
    Case("fuse-output-under-file", "fuse -o SCENE/pair.txt/x.ply", into_scene("fuse", "pair.txt", "x.ply"),
         "which is a file, not a folder"),
    Case("mesh-output-under-file", "mesh -o SCENE/pair.txt/x.ply", into_scene("mesh", "pair.txt", "x.ply"),
         "which is a file, not a folder"),
    Case("report-output-under-file", "report -o SCENE/pair.txt/x.html", into_scene("report", "pair.txt", "x.html"),
         "which is a file, not a folder"),
    Case("export-target-under-file", "export OUT --to colmap FILE/ws",
         lambda d: ["export", str(fused_folder(d)), "--to", "colmap", str(_file(d, "f") / "ws"), "--quiet"],
         "which is a file, not a folder"),
    Case("eval-json-under-file", "evaluate --json SCENE/pair.txt/x.json",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "1",
                    "--json", str(scene(d) / "pair.txt" / "x.json")], "which is a file, not a folder"),
    Case("output-name-too-long", "fuse -o with a file name of 300 bytes",
         lambda d: ["fuse", str(fused_folder(d)), "-o", str(d / ("a" * 300 + ".ply")), "--quiet"],
         "304 bytes long"),
    Case("input-name-too-long", "info on a path whose name has 300 bytes",
         lambda d: ["info", str(d / ("a" * 300))], "longer than the file system allows"),
    Case("mesh-truncation-huge", "mesh --truncation 1e9 (a negative tensor size)", mesh("--truncation", "1e9"),
         "--truncation"),
    Case("mesh-threads-huge", "mesh --method poisson --threads 100000 (a crash in MeshLab)",
         mesh("--method", "poisson", "--threads", "100000", fused=True), "--threads must be 1 .. CORES"),
    Case("mesh-threads-more-than-cores", "mesh --method poisson --threads 1000 (hung, its threads spinning)",
         mesh("--method", "poisson", "--threads", "1000", fused=True), "--threads must be 1 .. CORES"),
    Case("mesh-poisson-coincident-points", "mesh --method poisson on a fused cloud whose points all coincide",
         _coincident_cloud, "all lie at one place"),
    Case("recon-depth-range-extreme", "--depth-range 1e-300 1e300",
         lambda d: recon(d, "--depth-range", "1e-300", "1e300"), "single precision"),
    Case("recon-focal-tiny", "a focal length of 1e-9 pixels", _focal(1e-9), "field of view of 180 degrees"),
    Case("recon-translation-huge", "a camera translation of 1e30", _translation, "camera centre lies 1e\\+30"),
    Case("train-recipe-binary", "a binary file as the training recipe", _binary_recipe, "not a YAML text file"),
    Case("synth-seed-huge", "synth --seed 2**70", lambda d: ["synth", str(d / "s"), "--seed", str(2**70)], "--seed"),
    Case("eval-plot-format-unknown", "evaluate --plot p.xyz (a format matplotlib has not)",
         lambda d: ["evaluate", "cloud", str(cloud(d / "p.ply")), str(cloud(d / "g.ply")), "--threshold", "1",
                    "--plot", str(d / "p.xyz")], "cannot write a .xyz plot"),
    Case("tnt-into-dev-null", "evaluate tnt-submit /dev/null ...", lambda d: _tnt(d, Path("/dev/null")),
         "not a folder"),
    # the output guard, round 4: unclear messages
    Case("fuse-memory-tiny", "fuse --memory-gb 1e-9", lambda d: ["fuse", str(fused_folder(d)), "--memory-gb", "1e-9"],
         "need about [0-9]+ [KM]B; raise --memory-gb to at least"),
    Case("mesh-voxel-huge", "mesh --voxel 1e6 (larger than the scene)", mesh("--voxel", "1e6"),
         "larger than an eighth of the scene box"),
    Case("mesh-trim-everything", "mesh --method poisson --trim 99.999",
         mesh("--method", "poisson", "--trim", "99.999", fused=True), "--trim"),
    Case("eval-depth-masks-black", "evaluate depth --mask-dir with all-black masks", _black_depth_masks,
         "the masks mark no pixel"),
    Case("report-read-only", "report into a read-only folder (named by the report, not its temporary)",
         lambda d: ["report", str(fused_folder(d))], r"scene/report\.html: cannot write this file \(Read-only",
         patch=lambda mp: _read_only_place(mp, ".tmp")),
    Case("fuse-lock-read-only", "fuse -o into a read-only folder (named by the cloud, not its lock)",
         lambda d: ["fuse", str(fused_folder(d)), "-o", str(d / "plain" / "f.ply"), "--quiet"],
         r"plain/f\.ply: cannot write to the output file \(Read-only",
         patch=lambda mp: _read_only_place(mp, ".lock")),
    Case("train-height-huge", "train --height 100000", lambda d: ["train", "synthetic", "-o", str(d / "run"),
                                                                  "--height", "100000"], "at most 4096"),
    Case("train-max-steps-zero", "train --max-steps 0",
         lambda d: ["train", "synthetic", "-o", str(d / "run"), "--max-steps", "0"], "max_steps must be at least 1"),
    Case("recon-checkpoint-folder", "--checkpoint naming a folder", lambda d: recon(d, "--checkpoint", str(d)),
         "a folder, not a checkpoint file"),
    Case("train-checkpoint-folder", "train --checkpoint naming a folder",
         lambda d: ["train", "synthetic", "-o", str(d / "run"), "--checkpoint", str(d)],
         "a folder, not a checkpoint file"),
    Case("export-onnx-opset-too-old", "export-onnx --opset 16 (older than the graphs' operators)",
         lambda d: ["export-onnx", "-o", str(d / "m"), "--opset", "16", "--quiet"], "opset 17"),
    Case("export-onnx-views-out-of-range", "export-onnx --views 11",
         lambda d: ["export-onnx", "-o", str(d / "m"), "--views", "11", "--quiet"], "between 2 and 10"),
    Case("export-onnx-checkpoint-other-preset", "export-onnx --preset paper with the lite preset's weights",
         lambda d: ["export-onnx", "-o", str(d / "m"), "--preset", "paper", "--checkpoint",
                    str(shutil.copy(ROOT / "src/mvsformerpp/assets/weights/mvsformerpp-lite-synthetic.safetensors",
                                    d / "lite.safetensors")), "--quiet"],
         "'lite' preset"),
    Case("export-onnx-output-not-empty", "export-onnx -o a folder of the user's own files",
         lambda d: ["export-onnx", "-o", str(_file(d, "notes.txt").parent), "--quiet"], "not empty"),
    Case("export-onnx-missing-extra", "export-onnx where onnxruntime is not installed",
         lambda d: ["export-onnx", "-o", str(d / "m"), "--quiet"], r"mvsformerpp\[onnx\]",
         patch=lambda mp: mp.setitem(sys.modules, "onnxruntime", None)),
    Case("recon-onnx-model-without-backend", "reconstruct --onnx-model DIR without --backend onnxruntime",
         lambda d: recon(d, "--onnx-model", str(onnx_folder(d))), "--backend onnxruntime"),
    Case("recon-onnx-bf16", "reconstruct --backend onnxruntime --precision bf16",
         lambda d: recon(d, "--backend", "onnxruntime", "--precision", "bf16"), "fp32"),
    Case("recon-onnx-not-a-model", "reconstruct --onnx-model a folder without model.json",
         lambda d: recon(d, "--backend", "onnxruntime", "--onnx-model", str(_file(d, "notes.txt").parent)),
         "no model.json"),
    Case("recon-onnx-other-views", "reconstruct --onnx-model of a model exported for 5 views, the run uses 3",
         lambda d: recon(d, "--backend", "onnxruntime", "--onnx-model", str(onnx_folder(d, num_views=5))),
         "exported for 5 views"),
    Case("recon-onnx-other-temperatures", "reconstruct --onnx-model of a model with other temperatures baked in",
         lambda d: recon(d, "--backend", "onnxruntime", "--onnx-model",
                         str(onnx_folder(d, num_views=3, temperatures=(1.0, 1.0, 1.0, 1.0)))), "temperatures"),
    Case("recon-onnx-other-weights", "reconstruct --onnx-model of a model exported from a checkpoint, run without",
         lambda d: recon(d, "--backend", "onnxruntime", "--onnx-model", str(onnx_folder(d, num_views=3, checkpoint=str(
             shutil.copy(ROOT / "src/mvsformerpp/assets/weights/mvsformerpp-lite-synthetic.safetensors",
                         d / "mine.safetensors"))))), "--checkpoint it was exported from"),
    Case("recon-onnx-changed-graph", "reconstruct --onnx-model of a folder whose graph changed after the export",
         _changed_onnx_graph, "does not match model.json"),
    Case("recon-onnx-runtime-too-old", "reconstruct --onnx-model of graphs in an opset newer than onnxruntime's",
         lambda d: recon(d, "--backend", "onnxruntime", "--onnx-model", str(onnx_folder(d, opset=29, num_views=3))),
         "cannot load this graph"),
]


# ------------------------------------------------------------------------------------------ running
def run_case(case: Case, folder: Path) -> tuple[int | None, str, str]:
    """(exit code or None if it raised, stderr, the traceback if one escaped) for one case."""
    import traceback

    import pytest

    from mvsformerpp.cli import main

    argv = case.build(folder)
    err, out = io.StringIO(), io.StringIO()
    mp = pytest.MonkeyPatch()
    try:
        if case.patch is not None:
            case.patch(mp)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                rc = main(argv)
            except SystemExit as e:
                rc = e.code if isinstance(e.code, int) else 1
            except BaseException:
                return None, err.getvalue(), traceback.format_exc()
    finally:
        mp.undo()
    return rc, err.getvalue(), ""


def normalise(message: str, folder: Path) -> str:
    """The message with the case's folder shown as ``DIR``, the installed package as ``PACKAGE`` and this
    machine's number of CPU cores as ``CORES``."""
    for f in {str(folder.resolve()), str(folder)}:
        message = message.replace(f, "DIR")
    message = message.replace(str(package_file()), "PACKAGE")
    message = message.replace(f" 1 .. {cores()} (the CPU cores", " 1 .. CORES (the CPU cores")
    return message.strip()


def row(case: Case, message: str) -> str:
    cell = message.replace("|", "\\|")
    return f"| `{case.id}` | {case.what} | {cell} |"


HEADER = """# Bad inputs and their messages

Every bad input below was run by the test suite (`tests/cli/test_bad_inputs.py`): each ends with exit
code 2 and exactly this one line on stderr, nothing else (no traceback), and no file of the user's is
changed. `DIR` stands for the folder the test ran in. The table is generated from the tests
(`python tests/cli/bad_inputs.py --write docs/bad-inputs.md`), and a test fails when a message here
differs from what the command prints.

Other failures the suite provokes, beyond one-line messages:

- `kill -9` in the middle of a run, then the same command again: the result is byte for byte the one
  of an uninterrupted run, and the temporaries of the killed run are gone (`reconstruct`:
  `tests/pipelines/test_output_safety.py`; `fuse`, killed inside its final write:
  `tests/pipelines/test_input_checks.py`; `train --resume`: `tests/training/test_train_slow.py`, where the
  resumed run's `last.safetensors` and `last.state.pt` (optimiser, schedule, random state) are byte for byte
  the uninterrupted run's). A kill at any instant of saving a checkpoint leaves a pair to resume from
  (`tests/training/test_checkpoints.py`).
- `synth` killed (`kill -9`, Ctrl-C) or stopped by a full disk, then the same command: the set is completed,
  byte for byte the uninterrupted one (`tests/synth/test_synth_resume.py`). `export --overwrite` killed before
  the old workspace is renamed aside, between that and renaming the new one in, or before deleting the old
  one: the same command puts the old one back or finishes, and leaves the new workspace and no temporary
  (`tests/pipelines/test_export.py`; the first and last instants in the slow suite). Ctrl-C while `train` saves
  a checkpoint: the save ends whole, the run stops with exit code 130, `--resume` goes on
  (`tests/training/test_train.py`).
- Two processes writing into one folder, or into one file of a folder of the user's (`fuse -o f.ply`), or
  two `synth` runs into one folder: the second stops and names the first's pid and host
  (`tests/pipelines/test_output_safety.py`, `tests/synth/test_synth_resume.py`).
- Every command that writes, against one table of places it must not write (inside the installed package,
  an input, a file of another run or kind, a file of the user's of the same format, under a file, a name
  over 255 bytes, a folder for a file and a file for a folder, a symbolic link to an input): one `error:`
  line and not a byte changed (`tests/cli/test_forbidden_targets.py`; the rules: `docs/output-guard.md`).
- Checkpoints crafted to run code when unpickled (a pickled `os.system` call, alone or inside an
  official-layout dict; torch zip files whose pickle walks `_rebuild_tensor_v2.__builtins__.get` to
  `eval` by a protocol-4 dotted name; a dotted tail on an admitted name): each is shown to run under
  an unrestricted load, then refused without running (`tests/models/test_checkpoint.py`).
- Inputs that used to be misread are now read as meant: 32-bit float TIFF photos (intensities in [0, 1]),
  masks with an alpha channel, text files saved with a UTF-8 byte order mark (`tests/io/`); `--views`
  beyond the scene's images is capped at them, with a warning (`tests/pipelines/test_reconstruct.py`); a
  folder name holding bytes that are not UTF-8 is written and printed back as those bytes
  (`tests/viewer/test_report.py`).
- Resume after editing one depth line, one `pair.txt` line or one photo recomputes exactly the views
  that depend on it (`tests/pipelines/test_resume_validity.py`).

| case | bad input | message |
|---|---|---|
"""


def render(rows: list[str]) -> str:
    return HEADER + "\n".join(rows) + "\n"


def main(argv: list[str]) -> int:
    import torch

    rows = []
    for case in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            if case.needs_no_cuda and torch.cuda.is_available():
                print(f"skipping {case.id}: this machine has CUDA", file=sys.stderr)
                continue
            rc, err, tb = run_case(case, folder)
            if tb or rc == 0:
                print(f"{case.id}: exit {rc}\n{tb}{err}", file=sys.stderr)
            rows.append(row(case, normalise(err, folder)))
    text = render(rows)
    if len(argv) == 2 and argv[0] == "--write":
        Path(argv[1]).parent.mkdir(parents=True, exist_ok=True)
        Path(argv[1]).write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
