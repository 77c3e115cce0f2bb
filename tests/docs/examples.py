"""The runnable examples of the README and the documentation site, and the inputs they name.

A fenced ```bash or ```python block is an example that the tests run when the line above its fence is a
marker (the pages' source says so; readers do not see it):

    <!-- run -->                         run by the default test suite
    <!-- run slow -->                    run by the slow suite (pytest -m slow, make test-all)
    <!-- run cuda -->                    run where CUDA is present (skipped elsewhere); slow
    <!-- run serve -->                   a server: it must print its http:// address and answer there, then it
                                         is stopped
    <!-- run slow with my_photos -->     ... in a folder that holds the named inputs (INPUTS below)
    <!-- not run: REASON -->             shown, never run (every README block carries one of these markers)

The examples of one page run in order in one empty folder, Python blocks in one namespace, shell blocks in
``bash -e -o pipefail`` with the package's commands on PATH. The default suite runs a page's plain ``run``
blocks and skips the others; the slow suite runs them all in order. An input named after ``with`` is put
into the folder before its block runs unless the folder has it already (an earlier block of the page made
it).
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import torch

import mvsformerpp
from mvsformerpp.models import build_model
from mvsformerpp.pipelines.demo import temple_dir
from mvsformerpp.pipelines.export import export_colmap

ROOT = Path(__file__).resolve().parents[2]
MARKER = re.compile(r"^<!-- (run(?: [\w./ -]*)?|not run: .+) -->$")
FENCE = re.compile(r"^```(\w+)\s*$")
# A comment whose first word is "run" (or "not run") but that MARKER does not read is a typo; other comments
# (e.g. one naming a script, "<!-- run_view_set.py -->") are the page's own.
LOOKS_LIKE_MARKER = re.compile(r"^<!-- (not )?run\b(?![_.-])")
FLAGS = {"slow", "cuda", "serve"}


@dataclasses.dataclass(frozen=True)
class Example:
    page: str          # path relative to the repository root
    line: int          # line of its opening fence
    language: str      # bash or python
    code: str
    run: bool          # False: a "not run" block
    flags: frozenset[str] = frozenset()
    inputs: tuple[str, ...] = ()

    @property
    def tier(self) -> str:
        """"default", "slow" or "cuda": the suite that runs it."""
        return "cuda" if "cuda" in self.flags else "slow" if "slow" in self.flags else "default"


def pages() -> list[Path]:
    """README.md and every page of the documentation site."""
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def parse_marker(text: str) -> tuple[bool, frozenset[str], tuple[str, ...]]:
    """(run, flags, inputs) of a marker's text (without ``<!-- -->``); ValueError if it is malformed."""
    if text.startswith("not run: "):
        return False, frozenset(), ()
    words = text.split()[1:]
    flags, inputs = [], []
    if "with" in words:
        k = words.index("with")
        words, inputs = words[:k], words[k + 1:]
        if not inputs:
            raise ValueError("'with' names no input")
    unknown = [w for w in words if w not in FLAGS] + [i for i in inputs if i not in INPUTS]
    if unknown:
        raise ValueError(f"unknown words {unknown} (flags: {sorted(FLAGS)}; inputs: {sorted(INPUTS)})")
    flags = words
    return True, frozenset(flags), tuple(inputs)


def examples(path: Path) -> list[Example]:
    """The marked blocks of one page, in order; ValueError for a marker that is not right above a fence."""
    lines = path.read_text().splitlines()
    out = []
    for k, line in enumerate(lines):
        m = MARKER.match(line.strip())
        if not m:
            if LOOKS_LIKE_MARKER.match(line.strip()):
                raise ValueError(f"{path.name}:{k + 1}: malformed example marker {line.strip()!r}")
            continue
        fence = FENCE.match(lines[k + 1]) if k + 1 < len(lines) else None
        if not fence or fence.group(1) not in ("bash", "python"):
            raise ValueError(f"{path.name}:{k + 1}: an example marker must stand right above a ```bash or "
                             "```python fence")
        end = next(j for j in range(k + 2, len(lines)) if lines[j].startswith("```"))
        run, flags, inputs = parse_marker(m.group(1))
        page = str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name
        out.append(Example(page, k + 2, fence.group(1), "\n".join(lines[k + 2:end]) + "\n",
                           run, flags, inputs))
    return out


def unmarked_blocks(path: Path) -> list[int]:
    """Lines of the ```bash and ```python fences of ``path`` with no marker above them."""
    lines = path.read_text().splitlines()
    out, inside = [], False
    for k, line in enumerate(lines):
        if line.startswith("```"):
            if not inside and FENCE.match(line) and FENCE.match(line).group(1) in ("bash", "python"):
                if k == 0 or not MARKER.match(lines[k - 1].strip()):
                    out.append(k + 1)
            inside = not inside
    return out


# ---- running ------------------------------------------------------------------------------------------------


def command_env() -> dict[str, str]:
    """The environment of a shell example: this interpreter's commands first on PATH."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("MPLBACKEND", "Agg")
    return env


def run_shell(example: Example, cwd: Path, timeout: float = 1800) -> None:
    proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", example.code], cwd=cwd, env=command_env(),
                          capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError(f"{example.page}:{example.line} exited with {proc.returncode}:\n"
                             f"{example.code}\n--- stdout\n{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}")


def run_server(example: Example, cwd: Path, timeout: float = 300) -> str:
    """Start a serving example, wait for its address, fetch it, stop it; the address it printed."""
    proc = subprocess.Popen(["bash", "-e", "-o", "pipefail", "-c", example.code], cwd=cwd, env=command_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    seen, url = [], None
    try:
        end = time.monotonic() + timeout
        while url is None and time.monotonic() < end:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                break
            seen.append(line)
            m = re.search(r"https?://[\w.\-\[\]:]+(?::\d+)?/?\S*", line)
            url = m.group(0) if m else None
        if url is None:
            raise AssertionError(f"{example.page}:{example.line} printed no address:\n{''.join(seen)[-3000:]}")
        local = re.sub(r"//(0\.0\.0\.0|\[::\])", "//127.0.0.1", url)
        for _ in range(60):
            try:
                with urllib.request.urlopen(local, timeout=10) as response:
                    assert response.status == 200, f"{local} answered {response.status}"
                    break
            except OSError:
                time.sleep(1)
        else:
            raise AssertionError(f"{example.page}:{example.line}: nothing answers at {local}")
        return url
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        proc.stdout.close()


def run_python(example: Example, cwd: Path, namespace: dict) -> None:
    previous = os.getcwd()
    os.chdir(cwd)
    try:
        exec(compile(example.code, f"{example.page} block at line {example.line}", "exec"), namespace)
    finally:
        os.chdir(previous)


# ---- the inputs examples may name ---------------------------------------------------------------------------


def _temple_photos(dest: Path, cache: Path) -> None:
    """A folder of photos without cameras: the bundled temple's 16 PNG files."""
    dest.mkdir()
    for p in sorted(temple_dir().glob("*.png")):
        shutil.copy(p, dest / p.name)


def _small_reconstruction(dest: Path, cache: Path) -> None:
    """A finished ``reconstruct`` output folder (the temple, 3 views at 160x120), made once per session."""
    made = cache / "my_scene"
    if not made.is_dir():
        config = mvsformerpp.ReconstructConfig(max_size=160, max_images=3)
        mvsformerpp.reconstruct(mvsformerpp.sample_scene_path(), made, config, quiet=True)
    shutil.copytree(made, dest, symlinks=True)


def _colmap_project(dest: Path, cache: Path) -> None:
    """A COLMAP project (``images/``, ``sparse/``: pinhole cameras, poses, 3-D points with their observations):
    the small reconstruction exported with ``mvsformerpp export --to colmap``, made once per session."""
    made = cache / "my_colmap_project"
    if not made.is_dir():
        _small_reconstruction(cache / "exported_scene", cache)
        export_colmap(cache / "exported_scene", made, quiet=True)
    shutil.copytree(made, dest, symlinks=True)


def _official_checkpoint(dest: Path, cache: Path) -> None:
    """A checkpoint in the official trainer's layout (``module.`` keys under ``state_dict``) for the paper
    preset, with the randomly initialised weights of ``build_model("paper")``: the official file's form,
    not its values (they are not bundled). Made once per session and linked."""
    made = cache / "model_best.pth"
    if not made.is_file():
        torch.manual_seed(0)
        sd = build_model("paper").state_dict()
        torch.save({"arch": "DINOv2MVSNet", "epoch": 0, "state_dict": {f"module.{k}": v for k, v in sd.items()}},
                   made)
    dest.symlink_to(made)


def _dtu_test_set(dest: Path, cache: Path) -> None:
    """``dtu_test/scan1`` in the MVSNet test layout (images/, cams/, pair.txt), from the bundled DTU pair: two
    640x512 views whose cams hold K for the 160x128 depth grid (the reader scales K to the photos, and says
    so)."""
    pair = ROOT / "tests" / "data" / "dtu_pair"
    scan = dest / "scan1"
    (scan / "images").mkdir(parents=True)
    (scan / "cams").mkdir()
    for i in (0, 1):
        shutil.copyfile(pair / f"rect_{i + 1:03d}_0_r5000.png", scan / "images" / f"{i:08d}.png")
        shutil.copyfile(pair / f"{i:08d}_cam.txt", scan / "cams" / f"{i:08d}_cam.txt")
    (scan / "pair.txt").write_text("2\n0\n1 1 1.0\n1\n1 0 1.0\n")


def _checkout(dest: Path, cache: Path) -> None:
    """The checkout's files a command run from the repository root uses, linked into the folder (``dest`` is
    the folder itself here)."""
    for name in ("Makefile", "pyproject.toml", "src", "configs", "bench", "tools", "tests", ".venv"):
        if (ROOT / name).exists() and not (dest.parent / name).exists():
            (dest.parent / name).symlink_to(ROOT / name)


# name -> (what it is, the function that puts it at the folder's path of that name)
INPUTS = {
    "my_photos": _temple_photos,
    "my_scene": _small_reconstruction,
    "my_colmap_project": _colmap_project,
    "model_best.pth": _official_checkpoint,
    "dtu_test": _dtu_test_set,
    "checkout": _checkout,
}


def provide(names: tuple[str, ...], folder: Path, cache: Path) -> None:
    """Put each named input into ``folder`` unless it is there already."""
    for name in names:
        target = folder / name
        if name == "checkout":
            _checkout(target, cache)
        elif not target.exists() and not target.is_symlink():
            INPUTS[name](target, cache)
