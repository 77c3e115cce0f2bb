"""DTU and BlendedMVS training sets in their official layouts, as :class:`SceneDataset` entries.

DTU (the raw-resolution training release the reference trains on)::

    Cameras/pair.txt, Cameras/{vid:08d}_cam.txt                        K for the 1600x1200 photos
    Rectified_raw/scanN/rect_{vid+1:03d}_{light}_r5000.png             light 0..6
    Depths_raw/scanN/depth_map_{vid:04d}.pfm, depth_visual_{vid:04d}.png   (mask: value > 10)

BlendedMVS (``PID`` = scene id; some releases nest ``PID/PID/PID``)::

    PID/blended_images/{vid:08d}.jpg, PID/cams/{vid:08d}_cam.txt, PID/cams/pair.txt,
    PID/rendered_depth_maps/{vid:08d}.pfm                              (mask: depth > 0)

Scan lists: one name per line (``scan1`` or ``1``; blank lines and ``#`` comments ignored). The
standard DTU lists (train 79, val 18, test 22, trainval 97 scans) ship in ``mvsformerpp/data/lists/dtu``.
"""

from __future__ import annotations

from pathlib import Path

from mvsformerpp.data.scenes import SceneEntry
from mvsformerpp.errors import InputError
from mvsformerpp.io.benchmarks import blended_scene_dir, load_blended_scene, load_dtu_scene

LISTS = Path(__file__).resolve().parent / "lists"


def dtu_list(name: str) -> Path:
    """A shipped DTU scan list: ``train``, ``val``, ``test`` or ``trainval``."""
    return LISTS / "dtu" / f"{name}.txt"


def read_list(path: str | Path) -> list[str]:
    path = Path(path)
    if not path.is_file():
        raise InputError("scan list not found", path)
    names = [line.split("#")[0].strip() for line in path.read_text().splitlines()]
    names = [n for n in names if n]
    if not names:
        raise InputError("the scan list is empty", path)
    return names


def _require(path: Path, root: Path, what: str) -> None:
    if not path.exists():
        raise InputError(f"not the expected {what} layout: {path.relative_to(root)} is missing", root)


def dtu_entries(root: str | Path, scans: list[str], lights: tuple[int, ...], num_depth: int = 192,
                interval_scale: float = 1.06, list_path: str | Path | None = None) -> list[SceneEntry]:
    """One entry per (scan, light); checks the layout and every file a sample will read."""
    root = Path(root)
    if not root.is_dir():
        raise InputError("DTU data root not found (give it with --data-root)", root)
    _require(root / "Cameras" / "pair.txt", root, "DTU")
    names = [f"scan{s}" if s.isdigit() else s for s in scans]
    absent = [n for n in names if not (root / "Rectified_raw" / n).is_dir()]
    if absent:
        where = f" (listed in {list_path})" if list_path else ""
        raise InputError(f"{len(absent)} scan(s){where} are not in this DTU root: {', '.join(absent[:10])}"
                         f"{' ...' if len(absent) > 10 else ''} (expected Rectified_raw/{absent[0]}/)", root)
    entries = []
    for name in names:
        scene = load_dtu_scene(root, name, light=lights[0], resolution="raw", num_depth=num_depth,
                               interval_scale=interval_scale)
        for v in scene.views:
            vid = int(v.name)
            depth = root / "Depths_raw" / name / f"depth_map_{vid:04d}.pfm"
            _require(depth, root, "DTU")
            _require(root / "Depths_raw" / name / f"depth_visual_{vid:04d}.png", root, "DTU")
            v.depth_gt_path = depth
            v.mask_path = root / "Depths_raw" / name / f"depth_visual_{vid:04d}.png"
            for light in lights:
                _require(root / "Rectified_raw" / name / f"rect_{vid + 1:03d}_{light}_r5000.png", root, "DTU")
        for light in lights:
            def photo(i, scene=scene, name=name, light=light):
                return root / "Rectified_raw" / name / f"rect_{int(scene.views[i].name) + 1:03d}_{light}_r5000.png"

            entries.append(SceneEntry(f"{name} light {light}", scene, photo))
    return entries


def blended_entries(root: str | Path, scenes: list[str], num_depth: int = 192, interval_scale: float = 1.06,
                    list_path: str | Path | None = None) -> list[SceneEntry]:
    """One entry per BlendedMVS scene; checks the layout and every depth map a sample will read."""
    root = Path(root)
    if not root.is_dir():
        raise InputError("BlendedMVS data root not found (give it with --data-root)", root)
    absent = [s for s in scenes if blended_scene_dir(root / s) is None]
    if absent:
        where = f" (listed in {list_path})" if list_path else ""
        raise InputError(f"{len(absent)} scene(s){where} are not in this BlendedMVS root: {', '.join(absent[:5])}"
                         f"{' ...' if len(absent) > 5 else ''} (expected {absent[0]}/blended_images/ and "
                         f"{absent[0]}/cams/, possibly nested as {absent[0]}/{absent[0]}/{absent[0]}/)", root)
    entries = []
    for s in scenes:
        scene = load_blended_scene(root / s, num_depth=num_depth, interval_scale=interval_scale)
        for v in scene.views:
            if v.depth_gt_path is None:
                raise InputError(f"not the expected BlendedMVS layout: rendered_depth_maps/{v.name}.pfm is missing",
                                 scene.root)
        entries.append(SceneEntry(s, scene))
    return entries
