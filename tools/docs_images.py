"""The pictures of docs/images: the demo run's report, viewer, a depth map with its confidence, the TSDF mesh
and the Poisson meshes.

    python tools/docs_images.py OUT        # OUT: a `mvsformerpp demo -o OUT` folder (with report.html)

Writes docs/images/report.png (headless Chromium's rendering of OUT/report.html, its first 1280x1400
pixels, with this machine's folders shortened to OUT and the input's name) and docs/images/mesh.png
(OUT's TSDF mesh, made with `mvsformerpp mesh` if OUT/mesh.ply is missing, seen from the first camera:
each triangle's projection filled with its Lambert shade, nearest last), docs/images/poisson.png (Poisson
at depth 9: closed, cut by a 10 % density percentile, cut by the default distance rule; same view),
docs/images/depth.png (the first view's photo, its depth as fusion keeps it and its confidence, OUT's own
preview images side by side) and docs/images/viewer.png (`mvsformerpp view OUT` in headless Chromium after
its cloud has drawn).
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.output_folder import CONFIDENCE_VIS, DEPTH_VIS, open_run, view_stem
from mvsformerpp.io.ply import ply_points, read_ply, read_ply_faces
from mvsformerpp.viewer.app import ViewerConfig, start_viewer

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"


def report_png(out: Path, png: Path) -> None:
    """The report as a browser shows it, with this machine's folders shortened (OUT, the input's name)."""
    exe = _chromium()
    text = (out / "report.html").read_text()
    source = json.loads((out / "config.json").read_text()).get("input")
    if source:
        text = text.replace(source, Path(source).name)
    text = text.replace(str(out.resolve()), "OUT").replace(str(out), "OUT")
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "report.html"
        page.write_text(text)
        subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                        f"--user-data-dir={tmp}/profile", "--window-size=1280,1400", f"--screenshot={png}",
                        page.as_uri()], capture_output=True, timeout=120, check=False)
    if not png.is_file():
        sys.exit("error: chromium wrote no screenshot")
    Image.open(png).convert("RGB").quantize(256).save(png, optimize=True)


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        sys.exit("error: headless Chromium is needed (apt-get install chromium)")
    return exe


def mesh_png(out: Path, png: Path, size: int = 720, mesh: Path | None = None, *flags: str) -> None:
    """``mesh`` (default OUT/mesh.ply, made with ``mvsformerpp mesh OUT FLAGS`` when missing) from the first camera."""
    mesh = mesh or out / "mesh.ply"
    if not mesh.is_file():
        subprocess.run([sys.executable, "-m", "mvsformerpp", "mesh", str(out), "-o", str(mesh), "--quiet", *flags],
                       check=True)
    verts, faces = ply_points(read_ply(mesh)).astype(np.float64), read_ply_faces(mesh)
    view = load_mvsnet_scene(out).views[0]
    cam = verts @ view.R.T + view.t
    uv = cam @ view.K.T
    uv = uv[:, :2] / uv[:, 2:3]
    a, b, c = (verts[faces[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    light = view.R.T @ np.array([0.3, -0.5, -0.8])  # from above the camera, towards the scene
    shade = np.clip(np.abs(normal @ (-light / np.linalg.norm(light))), 0.0, 1.0)
    depth = cam[faces].mean(1)[:, 2]
    s = size / max(view.width, view.height)
    img = Image.new("RGB", (round(view.width * s), round(view.height * s)), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    for f in np.argsort(-depth):  # far first, so nearer triangles paint over
        g = int(40 + 200 * shade[f])
        draw.polygon([tuple(uv[v] * s) for v in faces[f]], fill=(g, g, int(g * 0.95)))
    img.quantize(64).save(png, optimize=True)


POISSON = (("closed (--watertight)", ("--watertight",)),
           ("10 % density cut", ("--max-distance", "0", "--trim", "10")),
           ("default: distance cut", ()))


def poisson_png(out: Path, png: Path, size: int = 420) -> None:
    """The three Poisson meshes of OUT side by side, each with its label."""
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, flags) in enumerate(POISSON):
            mesh, tile = Path(tmp) / f"p{k}.ply", Path(tmp) / f"p{k}.png"
            mesh_png(out, tile, size, mesh, "--method", "poisson", "--depth", "9", *flags)
            img = Image.open(tile).convert("RGB")
            ImageDraw.Draw(img).text((8, 8), label, fill=(0, 0, 0))
            tiles.append(img)
    w, h = tiles[0].size
    canvas = Image.new("RGB", (w * len(tiles), h), (255, 255, 255))
    for k, tile in enumerate(tiles):
        canvas.paste(tile, (k * w, 0))
    canvas.quantize(64).save(png, optimize=True)


def depth_png(out: Path, png: Path, view: int = 0, height: int = 300) -> None:
    """View ``view``'s photo, its depth as fusion keeps it and its confidence (OUT's previews), side by side."""
    stem = view_stem(view)
    sources = (open_run(out).views[view].image, out / DEPTH_VIS / f"{stem}.png", out / CONFIDENCE_VIS / f"{stem}.png")
    labels = ("photo", "depth (grey: dropped by fusion)", "confidence")
    tiles = []
    for path, label in zip(sources, labels):
        img = Image.open(path).convert("RGB")
        img = img.resize((round(img.width * height / img.height), height), Image.LANCZOS)
        ImageDraw.Draw(img).text((8, 8), label, fill=(255, 255, 255))
        tiles.append(img)
    canvas = Image.new("RGB", (sum(t.width for t in tiles) + 8 * (len(tiles) - 1), height), (255, 255, 255))
    x = 0
    for tile in tiles:
        canvas.paste(tile, (x, 0))
        x += tile.width + 8
    canvas.quantize(256).save(png, optimize=True)


def viewer_png(out: Path, png: Path, seconds: int = 20) -> None:
    """The viewer's page once its cloud has drawn (software WebGL), 1280x800."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    viewer = start_viewer(out, ViewerConfig(port=port, host="127.0.0.1", max_points=300_000))
    try:
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run([_chromium(), "--headless", "--no-sandbox", "--enable-unsafe-swiftshader",
                            "--hide-scrollbars", f"--user-data-dir={tmp}/profile", "--window-size=1280,800",
                            f"--virtual-time-budget={seconds * 1000}", f"--screenshot={png}", viewer.url],
                           capture_output=True, timeout=180, check=False)
    finally:
        viewer.stop()
    if not png.is_file():
        sys.exit("error: chromium wrote no screenshot of the viewer")
    Image.open(png).convert("RGB").quantize(256).save(png, optimize=True)


def main() -> None:
    if len(sys.argv) != 2 or not (Path(sys.argv[1]) / "report.html").is_file():
        sys.exit(__doc__)
    out = Path(sys.argv[1])
    IMAGES.mkdir(parents=True, exist_ok=True)
    report_png(out, IMAGES / "report.png")
    mesh_png(out, IMAGES / "mesh.png")
    poisson_png(out, IMAGES / "poisson.png")
    depth_png(out, IMAGES / "depth.png")
    viewer_png(out, IMAGES / "viewer.png")
    for name in ("report.png", "mesh.png", "poisson.png", "depth.png", "viewer.png"):
        print(f"wrote docs/images/{name} ({(IMAGES / name).stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    main()
