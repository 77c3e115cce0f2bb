"""``mvsformerpp view OUT``: the reconstruction in the browser, served by viser (the ``viewer`` extra).

What the page shows: the fused cloud (a random subset within a point budget), every camera as a frustum
with its photo, a panel with the chosen view's photo, depth map (as the report shows it: the pixels below
the run's fusion threshold grey, no-depth hatched, with a colour bar) and confidence map, and a
confidence slider that refilters the cloud live (on the per-point confidence that ``fuse`` stores).
Clicking a frustum selects its view. The server runs headless: open the printed URL from any browser
that can reach the machine (e.g. through ``ssh -L PORT:localhost:PORT``).
"""

from __future__ import annotations

import socket
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.geometry.resize import fit_long_side
from mvsformerpp.io.colmap_model import rotmat_to_qvec
from mvsformerpp.io.mvsnet import load_mvsnet_scene
from mvsformerpp.io.output_folder import RunFolder, ViewFiles, open_run
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply
from mvsformerpp.utils.colormap import depth_scale, kept_pixels, turbo
from mvsformerpp.viewer.report import depth_thumbnail, fusion_threshold, map_thumbnail


@dataclass(frozen=True)
class ViewerConfig:
    """Settings of :func:`start_viewer`."""

    port: int = 8080
    """Port to serve on; when it is taken, the next free one is used (and said)."""
    host: str = "0.0.0.0"
    """Interface to listen on (0.0.0.0: reachable from other machines; 127.0.0.1: this machine only)."""
    max_points: int = 1_000_000
    """Point budget: a larger cloud is shown as a random subset of this many points."""
    thumbnail: int = 320
    """Longer side of the photos on the frustums and in the panel, in pixels."""


@dataclass
class Cloud:
    """The points on display (after subsampling) and how many the file has."""

    xyz: np.ndarray
    rgb: np.ndarray
    confidence: np.ndarray | None
    total: int


@dataclass
class Viewer:
    """A running viewer: the viser server and the handles the GUI updates."""

    server: object
    url: str
    port: int
    run: RunFolder
    cloud: Cloud
    handles: dict = field(default_factory=dict)

    def shown(self, threshold: float) -> np.ndarray:
        """Indices of the displayed points with confidence at or above ``threshold``."""
        if self.cloud.confidence is None:
            return np.arange(len(self.cloud.xyz))
        return np.flatnonzero(self.cloud.confidence >= threshold)

    def set_threshold(self, threshold: float) -> int:
        """Refilter the cloud by confidence; returns the number of points shown."""
        keep = self.shown(threshold)
        cloud = self.handles["cloud"]
        cloud.points = self.cloud.xyz[keep]
        cloud.colors = self.cloud.rgb[keep]
        self.handles["status"].content = _status(len(self.run.views), len(keep), self.cloud.total)
        return len(keep)

    def stop(self) -> None:
        self.server.stop()


def _import_viser():
    try:
        import viser
    except ImportError as e:
        raise MissingDependencyError("viser", "viewer", "The browser viewer") from e
    return viser


def load_cloud(path: Path, max_points: int, seed: int = 0) -> Cloud:
    """Read a fused PLY, keeping a random subset of at most ``max_points`` points."""

    vertex = read_ply(path)
    xyz = ply_points(vertex, path).astype(np.float32)
    rgb = ply_colors(vertex)
    rgb = np.full((len(xyz), 3), 200, np.uint8) if rgb is None else rgb
    conf = vertex.get("confidence")
    total = len(xyz)
    if total > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(total, max_points, replace=False))
        xyz, rgb = xyz[keep], rgb[keep]
        conf = None if conf is None else conf[keep]
    return Cloud(xyz, rgb, None if conf is None else conf.astype(np.float32), total)


def _status(cameras: int, shown: int, total: int) -> str:
    return f"**{cameras} cameras** · {shown:,} of {total:,} points shown"


def _thumb(rgb: np.ndarray, side: int) -> np.ndarray:
    h, w = rgb.shape[:2]
    return np.asarray(Image.fromarray(rgb).resize(fit_long_side(w, h, side), Image.BILINEAR))


def with_colorbar(rgb: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``rgb`` with the colour scale below it: a gradient strip and its end values."""
    w = rgb.shape[1]
    bar = np.repeat(turbo(np.linspace(0.0, 1.0, w))[None], 10, axis=0)
    labels = Image.new("RGB", (w, 14), (255, 255, 255))
    draw = ImageDraw.Draw(labels)
    left, right = f"{lo:.4g}", f"{hi:.4g}"
    draw.text((1, 1), left, fill=(0, 0, 0))
    draw.text((max(1, w - 1 - int(draw.textlength(right))), 1), right, fill=(0, 0, 0))
    return np.concatenate([rgb, np.full((3, w, 3), 255, np.uint8), bar, np.asarray(labels)], axis=0)


def view_panels(view: ViewFiles, side: int, threshold: float | None = None) -> dict[str, np.ndarray]:
    """Photo, depth and confidence images of one view for the panel (missing ones left out). The depth is
    shown as fusion sees it (pixels at or below the confidence ``threshold`` grey, no depth hatched), with
    its colour bar; the confidence with its own on [0, 1]."""
    panels = {}
    image = view.read_image()
    if image is not None:
        panels["photo"] = _thumb(image, side)
    depth = view.read_depth()
    if depth is not None:
        conf = view.read_confidence()
        conf = conf if conf is not None and conf.shape == depth.shape else None
        valid, kept = kept_pixels(depth, conf, threshold)
        lo, hi = depth_scale(depth, kept, valid)
        panels["depth"] = with_colorbar(_thumb(depth_thumbnail(depth, conf, threshold, (lo, hi)), side), lo, hi)
        if conf is not None:
            panels["confidence"] = with_colorbar(_thumb(map_thumbnail(conf, 0.0, 1.0, np.isfinite(conf)), side),
                                                 0.0, 1.0)
    return panels


def check_host(host: str) -> None:
    """Refuse an address this machine cannot listen on (the web server would otherwise wait forever)."""
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as e:
        raise InputError(f"--host {host!r} is not an address or a name this machine can resolve ({e}); give one of "
                         "its addresses, e.g. 127.0.0.1 (this machine only) or 0.0.0.0 (all)") from e
    errors = []
    for family, kind, proto, _, addr in infos:
        try:
            with socket.socket(family, kind, proto) as probe:
                probe.bind(addr)
            return
        except OSError as e:
            errors.append(e.strerror or str(e))
    raise InputError(f"cannot listen on --host {host!r} ({'; '.join(dict.fromkeys(errors))}): give an address of "
                     "this machine, e.g. 127.0.0.1 (this machine only) or 0.0.0.0 (all)")


def start_viewer(folder: str | Path, config: ViewerConfig = ViewerConfig()) -> Viewer:
    """Load an output folder and serve it; returns at once (the server runs in background threads)."""
    check_host(config.host)  # first: a wrong address fails at once, whatever else is missing
    viser = _import_viser()
    run = open_run(folder)
    ply = run.cloud
    if ply is None:
        raise InputError("no fused cloud to show (fused.ply); make it with `mvsformerpp fuse OUT` or "
                         "`mvsformerpp reconstruct INPUT -o OUT` with fusion on", run.root)
    cloud = load_cloud(ply, config.max_points)
    scene = load_mvsnet_scene(run.root)
    server = viser.ViserServer(host=config.host, port=config.port, verbose=False)
    port = server.get_port()
    host = "localhost" if config.host in ("0.0.0.0", "::", "127.0.0.1") else config.host
    viewer = Viewer(server, f"http://{host}:{port}", port, run, cloud)
    extent = _place_camera(server, cloud, scene)
    viewer.handles["cloud"] = server.scene.add_point_cloud(
        "/cloud", points=cloud.xyz, colors=cloud.rgb, point_size=extent / 1500, point_shape="rounded")
    viewer.handles["status"] = server.gui.add_markdown(_status(len(scene.views), len(cloud.xyz), cloud.total))
    threshold = server.gui.add_slider("min confidence", min=0.0, max=1.0, step=0.01, initial_value=0.0,
                                      disabled=cloud.confidence is None)
    if cloud.confidence is None:
        server.gui.add_markdown("_This cloud has no per-point confidence: run `mvsformerpp fuse OUT` again._")
    threshold.on_update(lambda _: viewer.set_threshold(threshold.value))
    viewer.handles["threshold"] = threshold
    chooser = _add_view_panels(server, viewer, run, config)
    near = [v.depth_min for v in scene.views if v.depth_min]
    _add_cameras(server, scene, run, chooser, 0.08 * float(np.median(near)) if near else 0.03 * extent)
    return viewer


def _place_camera(server, cloud: Cloud, scene) -> float:
    """The scene's up direction and the opening camera: behind and above the cameras, looking at the middle
    of the cloud. Returns the cloud's extent (scene units)."""
    centres = np.stack([v.center for v in scene.views])
    lo, hi = (np.percentile(cloud.xyz, [1, 99], axis=0) if len(cloud.xyz) else (centres.min(0), centres.max(0)))
    extent = float(np.linalg.norm(hi - lo)) or 1.0
    target = (lo + hi) / 2
    up = -np.mean([v.R[1] for v in scene.views], axis=0)  # the photos' up (cameras look along +z, y down)
    up /= np.linalg.norm(up) or 1.0
    rig = centres.mean(0)
    server.initial_camera.position = tuple(rig + 0.5 * (rig - target) + 0.25 * extent * up)
    server.initial_camera.look_at = tuple(target)
    server.initial_camera.up = tuple(up)
    server.scene.set_up_direction(tuple(up))
    return extent


def _add_view_panels(server, viewer: Viewer, run: RunFolder, config: ViewerConfig):
    """The view chooser and the chosen view's photo, depth and confidence panels; returns the chooser."""
    chooser = server.gui.add_dropdown("view", options=tuple(f"{v.stem} {v.name}" for v in run.views))
    fusion_conf = fusion_threshold(run)
    first = view_panels(run.views[0], config.thumbnail, fusion_conf)
    images = {kind: server.gui.add_image(first[kind], label=kind) for kind in ("photo", "depth", "confidence")
              if kind in first}
    viewer.handles["panels"] = images

    def show_view(_=None) -> None:
        i = [f"{v.stem} {v.name}" for v in run.views].index(chooser.value)
        for kind, img in view_panels(run.views[i], config.thumbnail, fusion_conf).items():
            if kind in images:
                images[kind].image = img
    chooser.on_update(show_view)
    return chooser


def _add_cameras(server, scene, run: RunFolder, chooser, size: float) -> None:
    """Each camera as a frustum of ``size`` with its photo; a click on one chooses its view."""
    names = [v.name for v in run.views]
    for i, (view, files) in enumerate(zip(scene.views, run.views)):
        photo = files.read_image()
        frustum = server.scene.add_camera_frustum(
            f"/cameras/{files.stem}", fov=float(2 * np.arctan(view.height / (2 * view.K[1, 1]))),
            aspect=view.width / view.height, scale=size, wxyz=tuple(rotmat_to_qvec(view.R.T)),
            position=tuple(view.center), image=None if photo is None else _thumb(photo, 160), color=(230, 60, 40))

        def select(_, label=f"{files.stem} {names[i]}") -> None:
            chooser.value = label
        frustum.on_click(select)


def serve(folder: str | Path, config: ViewerConfig = ViewerConfig()) -> None:
    """Serve until interrupted (Ctrl-C), printing where to open the viewer."""
    viewer = start_viewer(folder, config)
    if viewer.port != config.port:
        print(f"port {config.port} is in use; serving on port {viewer.port} instead")
    print(f"viewer of {viewer.run.root} ({len(viewer.run.views)} cameras, {viewer.cloud.total:,} points): "
          f"{viewer.url}")
    if config.host == "0.0.0.0":
        print(f"  from another machine: http://{socket.gethostname()}:{viewer.port} "
              f"(or ssh -L {viewer.port}:localhost:{viewer.port} HOST, then {viewer.url})")
    print("Ctrl-C stops it", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
