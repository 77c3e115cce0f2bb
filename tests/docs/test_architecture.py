"""The worked examples of docs/architecture.md: each is applied, as written there, to a copy of the package
and run from its command line; a fusion method and an input format touch two files, a network preset one."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from mvsformerpp.io.mvsnet import read_cam
from mvsformerpp.io.ply import ply_vertex_count
from mvsformerpp.synth import generate_scene

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "architecture.md"
EXAMPLE = re.compile(r'<!-- example ([\w-]+): (?:new (\S+)|in (\S+), after "([^"]+)") -->\n```python\n(.*?)^```',
                     re.S | re.M)
FILES_TOUCHED = {"fusion-method": 2, "input-format": 2, "network-preset": 1}


def examples() -> dict[str, list[tuple[str, str | None, str]]]:
    """Example name -> its edits: (path, anchor (None: a new file), code), in the order of the page."""
    out: dict[str, list] = {}
    for name, new, where, anchor, code in EXAMPLE.findall(DOC.read_text()):
        out.setdefault(name, []).append((new or where, None if new else anchor, code))
    return out


def apply(edits, root: Path) -> None:
    """Write the new files and insert each snippet after the first line that starts with its anchor."""
    for path, anchor, code in edits:
        target = root / path
        if anchor is None:
            assert not target.exists(), f"{path} is not new"
            target.write_text(code)
            continue
        lines = target.read_text().splitlines(keepends=True)
        at = next(i for i, line in enumerate(lines) if line.startswith(anchor))
        target.write_text("".join(lines[:at + 1]) + code + "".join(lines[at + 1:]))


def package_with(name: str, tmp_path: Path) -> Path:
    """A copy of the package (its assets linked) with example ``name`` applied; returns the copy's root."""
    src = ROOT / "src" / "mvsformerpp"
    dst = tmp_path / "copy" / "src" / "mvsformerpp"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("assets", "__pycache__"))
    (dst / "assets").symlink_to(src / "assets")
    apply(examples()[name], tmp_path / "copy")
    return tmp_path / "copy"


def run(copy: Path, *args: str, code: str | None = None) -> str:
    """The copy's command line (or ``code`` in its Python); its standard output."""
    argv = [sys.executable, "-c", code] if code else [sys.executable, "-m", "mvsformerpp", *args]
    done = subprocess.run(argv, env={**os.environ, "PYTHONPATH": str(copy / "src")}, capture_output=True,
                          text=True, timeout=600, cwd=copy)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A small synthetic scene whose true depth maps stand in for estimated ones."""
    folder = generate_scene(tmp_path_factory.mktemp("arch") / "scene", seed=2, num_views=4, height=48, width=64,
                            gt_points=2000)
    shutil.copytree(folder / "depth_gt", folder / "depth_est")
    return folder


def test_the_examples_touch_as_few_files_as_the_page_says():
    found = examples()
    assert set(found) == set(FILES_TOUCHED)
    for name, edits in found.items():
        assert len({path for path, _, _ in edits}) == FILES_TOUCHED[name], name


def test_a_fusion_method_is_its_module_and_one_record(scene, tmp_path):
    copy = package_with("fusion-method", tmp_path)
    assert "unanimous" in run(copy, "fuse", "--help")
    clouds = {}
    for method in ("normal", "unanimous"):
        clouds[method] = tmp_path / f"{method}.ply"
        run(copy, "fuse", str(scene), "-o", str(clouds[method]), "--fusion", method, "--quiet")
    points = {method: ply_vertex_count(ply) for method, ply in clouds.items()}
    # every source agreeing is stricter than one agreeing (normal's default), and true depths agree
    assert 0 < points["unanimous"] <= points["normal"]


def test_an_input_format_is_its_reader_and_one_record(scene, tmp_path):
    copy = package_with("input-format", tmp_path)
    folder = tmp_path / "json_scene"
    folder.mkdir()
    views = []
    for cam_file in sorted((scene / "cams").glob("*_cam.txt")):
        cam, stem = read_cam(cam_file), cam_file.name[:8]
        shutil.copy(scene / "images" / f"{stem}.png", folder / f"{stem}.png")
        views.append({"image": f"{stem}.png", "K": cam.K.tolist(), "R": cam.extrinsic[:3, :3].tolist(),
                      "t": cam.extrinsic[:3, 3].tolist(), "depth_range": [cam.depth_min, cam.depth_max]})
    (folder / "cameras.json").write_text(json.dumps({"views": views}))
    summary = json.loads(run(copy, "info", str(folder), "--json"))
    assert summary["layout"] == "json" and summary["num_views"] == 4
    assert summary["neighbors"]["min"] >= 1


def test_a_network_preset_is_one_record(scene, tmp_path):
    copy = package_with("network-preset", tmp_path)
    for command in ("reconstruct", "demo", "info", "train"):
        assert "nano" in run(copy, command, "--help"), command
    assert "stage 1" in run(copy, "info", str(scene), "--preset", "nano")
    sizes = run(copy, code="from mvsformerpp.models import build_model\n"
                           "print(*(sum(p.numel() for p in build_model(n).parameters()) for n in ('nano', 'lite')))")
    nano, lite = map(int, sizes.split())
    assert nano < lite
