"""MVSNet scene layout: ``images/``, ``cams/NNNNNNNN_cam.txt``, ``pair.txt``.

A cam file (Yao et al., MVSNet, ECCV 2018; the layout every learned-MVS code base reads)::

    extrinsic
    r11 r12 r13 t1          4x4 world-to-camera
    r21 r22 r23 t2
    r31 r32 r33 t3
    0 0 0 1

    intrinsic
    fx 0 cx                 3x3, for the image the file goes with
    0 fy cy
    0 0 1

    DEPTH_MIN DEPTH_INTERVAL [DEPTH_NUM [DEPTH_MAX]]     or    DEPTH_MIN DEPTH_MAX

Depth planes are ``DEPTH_MIN + k * DEPTH_INTERVAL``, k = 0 .. DEPTH_NUM - 1 (192 planes when the
file does not say), so ``depth_max = DEPTH_MIN + DEPTH_INTERVAL * (DEPTH_NUM - 1)``.

The two-number line is ambiguous: ``425 2.5`` (DTU) is min + interval, ``0.5 12.0`` (several newer
converters) is min + max. ``depth_format="auto"`` reads it as min + max exactly when the second
number is larger than the first: as an interval that would put the last of 192 planes beyond
192 x DEPTH_MIN (a depth range spanning more than two orders of magnitude, which no MVS cam file
describes), while as a maximum it is a valid range. Otherwise it is min + interval (a maximum
below the minimum is impossible). ``depth_format="interval"`` or ``"max"`` forces either reading;
``"none"`` ignores the depth line.

pair.txt is read and written by :mod:`mvsformerpp.io.pair` (re-exported here).
"""

from __future__ import annotations

import logging
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.images import find_image, image_size
from mvsformerpp.io.pair import Pairs, format_pair, read_pair, write_pair
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.io.text import format_float, read_text
from mvsformerpp.io.viewselect import set_neighbors_from_cameras
from mvsformerpp.utils.atomic import atomic_open

log = logging.getLogger(__name__)

DepthFormat = Literal["auto", "interval", "max", "none"]
DEFAULT_NUM_DEPTH = 192
__all__ = [
    "DEFAULT_NUM_DEPTH", "DepthFormat", "MVSNetCam", "Pairs", "cam_files", "format_cam", "format_pair",
    "image_scale_factor", "load_mvsnet_scene", "read_cam", "read_pair", "report_scaling",
    "set_neighbors", "view_from_cam", "write_cam", "write_mvsnet_scene", "write_pair",
]
_CAM_RE = re.compile(r"^(\d+)_cam\.txt$")


@dataclass
class MVSNetCam:
    """One parsed cam file.

    ``extrinsic`` [4,4] world-to-camera; ``K`` [3,3]; depth fields are None when the file has no
    depth line (or ``depth_format="none"``). ``num_depth`` is the plane count the file states, else None.
    """

    extrinsic: np.ndarray
    K: np.ndarray
    depth_min: float | None = None
    depth_max: float | None = None
    depth_interval: float | None = None
    num_depth: int | None = None
    depth_line: str | None = None
    """How the depth line was read: ``MIN INTERVAL``, ``MIN MAX``, ``MIN INTERVAL NUM`` or ``MIN INTERVAL NUM MAX``."""

    @property
    def R(self) -> np.ndarray:
        return self.extrinsic[:3, :3]

    @property
    def t(self) -> np.ndarray:
        return self.extrinsic[:3, 3]


def _floats(tokens: list[str], path: Path, what: str) -> np.ndarray:
    try:
        vals = np.array([float(x) for x in tokens], dtype=np.float64)
    except ValueError as e:
        raise FormatError(f"{what}: expected numbers, got {' '.join(tokens)!r}", path) from e
    if not np.all(np.isfinite(vals)):
        shown = " ".join(tokens[:4]) + (" ..." if len(tokens) > 4 else "")
        raise FormatError(f"{what} contains non-finite numbers ({shown})", path)
    return vals


def _parse_depth(
    nums: np.ndarray, fmt: DepthFormat, num_depth: int, path: Path
) -> tuple[float, float, float, int | None]:
    """(depth_min, depth_max, depth_interval, stated plane count) from the depth line's numbers."""
    if len(nums) == 1:
        raise FormatError(
            f"depth line has only one number ({nums[0]:g}); expected 'DEPTH_MIN DEPTH_INTERVAL', "
            "'DEPTH_MIN DEPTH_MAX' or 'DEPTH_MIN DEPTH_INTERVAL DEPTH_NUM DEPTH_MAX'",
            path,
        )
    dmin = float(nums[0])
    stated: int | None = None
    if len(nums) == 2:
        second = float(nums[1])
        if fmt == "auto":
            fmt = "max" if second > dmin else "interval"
        if fmt == "max":
            dmax = second
            interval = (dmax - dmin) / (num_depth - 1)
        else:
            interval = second
            dmax = dmin + interval * (num_depth - 1)
    else:
        interval = float(nums[1])
        n = float(nums[2])
        if n < 2 or n != int(n):
            raise FormatError(f"depth line: DEPTH_NUM must be an integer >= 2, got {n:g}", path)
        stated = int(n)
        dmax = float(nums[3]) if len(nums) == 4 else dmin + interval * (stated - 1)
        if fmt == "max" and len(nums) == 3:
            raise FormatError("depth_format='max' but the depth line has no DEPTH_MAX", path)
    if not 0 < dmin < dmax:
        raise FormatError(
            f"depth range {dmin:g}..{dmax:g} from the depth line must satisfy 0 < min < max "
            "(check the file, read two numbers as --depth-format interval or max, or give --depth-range MIN MAX)",
            path,
        )
    return dmin, dmax, interval, stated


def read_cam(path: str | Path, depth_format: DepthFormat = "auto", num_depth: int = DEFAULT_NUM_DEPTH) -> MVSNetCam:
    """Read an MVSNet ``*_cam.txt`` file (see the module docstring for the format and depth forms).

    ``num_depth`` is the plane count assumed for the two-number forms.
    """
    path = Path(path)
    if depth_format not in ("auto", "interval", "max", "none"):
        raise ValueError(f"depth_format must be auto, interval, max or none, got {depth_format!r}")
    if num_depth < 2:
        raise ValueError(f"num_depth must be >= 2, got {num_depth}")
    tokens = read_text(path, "camera file", "camera file is not text (expected an MVSNet cam file)").split()
    lower = [t.lower() for t in tokens]
    if "extrinsic" not in lower or "intrinsic" not in lower:
        raise FormatError("not an MVSNet cam file: the 'extrinsic' and 'intrinsic' headers are missing", path)
    ie, ii = lower.index("extrinsic"), lower.index("intrinsic")
    if ie != 0 or ii != 17:
        raise FormatError(
            "not an MVSNet cam file: expected 'extrinsic', 16 numbers (4x4), 'intrinsic', 9 numbers (3x3), "
            f"then the depth line; found {ii - ie - 1} numbers after 'extrinsic'",
            path,
        )
    E = _floats(tokens[1:17], path, "extrinsic").reshape(4, 4)
    body = tokens[18:27]
    if len(body) < 9:
        raise FormatError(f"intrinsic: expected 9 numbers (3x3), found {len(body)}", path)
    K = _floats(body, path, "intrinsic").reshape(3, 3)
    depth_tokens = tokens[27:]
    if len(depth_tokens) > 4:
        raise FormatError(
            f"depth line: expected 2 to 4 numbers after the intrinsics, found {len(depth_tokens)} tokens", path
        )
    if not np.allclose(E[3], [0, 0, 0, 1], atol=1e-6):
        raise FormatError(f"extrinsic: last row must be 0 0 0 1, got {E[3].tolist()}", path)
    R = E[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-2) or np.linalg.det(R) < 0:
        raise FormatError("extrinsic: the 3x3 block is not a rotation matrix", path)
    if not np.allclose(K[2], [0, 0, 1], atol=1e-9) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise FormatError(f"intrinsic: expected [[fx,s,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0, got {K.tolist()}", path)
    cam = MVSNetCam(extrinsic=E, K=K)
    if depth_tokens and depth_format != "none":
        nums = _floats(depth_tokens, path, "depth line")
        cam.depth_min, cam.depth_max, cam.depth_interval, cam.num_depth = _parse_depth(
            nums, depth_format, num_depth, path
        )
        two = "MIN MAX" if depth_format == "max" or (depth_format == "auto" and nums[1] > nums[0]) else "MIN INTERVAL"
        cam.depth_line = {2: two, 3: "MIN INTERVAL NUM", 4: "MIN INTERVAL NUM MAX"}[len(nums)]
    return cam


def depth_line_forms(cam_dir: str | Path, depth_format: DepthFormat = "auto") -> dict[str, int]:
    """How many cam files in ``cam_dir`` had each depth-line form (see ``MVSNetCam.depth_line``)."""
    from collections import Counter

    forms = Counter(read_cam(p, depth_format).depth_line or "none" for p in cam_files(cam_dir).values())
    return dict(forms.most_common())


def format_cam(cam: MVSNetCam, num_depth: int = DEFAULT_NUM_DEPTH) -> str:
    """The cam file text, 4-number depth line ``MIN INTERVAL NUM MAX`` (omitted without a depth range)."""
    E = np.asarray(cam.extrinsic, dtype=np.float64).reshape(4, 4)
    K = np.asarray(cam.K, dtype=np.float64).reshape(3, 3)
    lines = ["extrinsic"]
    lines += [" ".join(format_float(v) for v in row) for row in E]
    lines += ["", "intrinsic"]
    lines += [" ".join(format_float(v) for v in row) for row in K]
    lines.append("")
    if cam.depth_min is not None and cam.depth_max is not None:
        n = cam.num_depth or num_depth
        interval = (cam.depth_max - cam.depth_min) / (n - 1)
        lines.append(f"{format_float(cam.depth_min)} {format_float(interval)} {n} {format_float(cam.depth_max)}")
    return "\n".join(lines) + "\n"


def write_cam(path: str | Path, cam: MVSNetCam, num_depth: int = DEFAULT_NUM_DEPTH) -> None:
    """Write a cam file atomically (4-number depth line; ``num_depth`` planes unless ``cam`` states one)."""
    vals = [cam.extrinsic, cam.K] + [v for v in (cam.depth_min, cam.depth_max) if v is not None]
    if not all(np.all(np.isfinite(np.asarray(v, dtype=np.float64))) for v in vals):
        raise ValueError(f"refusing to write non-finite camera values to {path}")
    with atomic_open(path, "w") as f:
        f.write(format_cam(cam, num_depth))


# ---------------------------------------------------------------------------------------------- scene


def cam_files(cam_dir: str | Path) -> dict[int, Path]:
    """``{view_id: path}`` for the ``NNNNNNNN_cam.txt`` files in ``cam_dir``."""
    out = {}
    for p in Path(cam_dir).iterdir():
        m = _CAM_RE.match(p.name)
        if m and p.is_file():
            vid = int(m.group(1))
            if vid in out:
                a, b = sorted((out[vid].name, p.name))
                raise InputError(f"two cam files for view {vid}: {a} and {b}; keep one of them", Path(cam_dir))
            out[vid] = p
    return dict(sorted(out.items()))


def image_scale_factor(K: np.ndarray, width: int, height: int, where: Path) -> float:
    """The factor s (1, an integer 2..8, or 1/s) by which ``K`` must be scaled for a ``width x height`` photo.

    A cam file does not state its image size; its principal point does, roughly. ``K`` is accepted as
    is when (cx, cy) lies within 10% of the image size from its centre. Otherwise, of the integer factors
    s = 2..8 and 1/s, the one putting s * (cx, cy) nearest the image centre is taken if that is within 10% of
    the image size; callers then use ``K[:2] *= s`` (the MVSNet convention for resized images, integer
    pixel coordinates) and log one warning per scene naming the factor. Anything else raises
    :class:`InputError`.
    """
    cx, cy = K[0, 2], K[1, 2]

    def off_centre(s: float) -> float:
        return max(abs(s * cx / width - 0.5), abs(s * cy / height - 0.5))

    if off_centre(1.0) <= 0.1:
        return 1.0
    factors = [float(v) for v in range(2, 9)] + [1.0 / v for v in range(2, 9)]
    best = min(factors, key=off_centre)
    if off_centre(best) <= 0.1:
        return best
    raise InputError(
        f"the camera's principal point ({cx:g}, {cy:g}) does not fit the {width}x{height} image (it lies more "
        "than 10% off the centre), nor any integer rescaling of it: the photo and the camera file do not belong "
        "together (use the photo at the resolution the camera was calibrated for)",
        where,
    )


def view_from_cam(
    name: str,
    cam_path: Path,
    image_path: Path,
    depth_format: DepthFormat = "auto",
    num_depth: int = DEFAULT_NUM_DEPTH,
    interval_scale: float = 1.0,
    scales: list[float] | None = None,
) -> View:
    """One View from a cam file and its photo (size from the header, K matched to it).

    The K scale factor used (:func:`image_scale_factor`) is appended to ``scales`` when given.
    """
    cam = read_cam(cam_path, depth_format=depth_format, num_depth=num_depth)
    w, h = image_size(image_path)
    s = image_scale_factor(cam.K, w, h, image_path)
    if scales is not None:
        scales.append(s)
    K = cam.K.copy()
    K[:2] *= s
    dmin, dmax = cam.depth_min, cam.depth_max
    if dmin is not None and dmax is not None and interval_scale != 1.0:
        dmax = dmin + (dmax - dmin) * interval_scale
    return View(name=name, image_path=image_path, width=w, height=h, K=K, R=cam.R, t=cam.t,
                depth_min=dmin, depth_max=dmax)


def report_scaling(where: Path, scales: list[float]) -> None:
    """One warning for the views whose K was rescaled to fit their photos."""
    scaled = [s for s in scales if s != 1.0]
    if scaled:
        factors = ", ".join(f"{s:g}" for s in sorted(set(scaled)))
        log.warning("%s: camera intrinsics of %d of %d views are for another image size; K scaled by %s to fit the "
                    "photos", where, len(scaled), len(scales), factors)


def set_neighbors(
    views: list[View], ids: list[int], pair_path: Path | None, num_neighbors: int = 10, skipped: set[int] = frozenset()
) -> None:
    """Fill ``views[i].neighbors`` from pair.txt (``ids[i]`` is view i's id there) or, without one, geometry.

    Ids in ``skipped`` (cameras the caller left out, e.g. without a photo) are dropped from the pairs;
    any other id the scene does not have is an error.
    """
    index = {vid: i for i, vid in enumerate(ids)}
    if pair_path is not None and pair_path.is_file():
        pairs = read_pair(pair_path)
        for ref, srcs in pairs.items():
            missing = [v for v in [ref] + [s for s, _ in srcs] if v not in index and v not in skipped]
            if missing:
                raise InputError(
                    f"pair file references view(s) {sorted(set(missing))} that have no camera in the scene",
                    pair_path,
                )
            if ref in index:
                views[index[ref]].neighbors = [index[s] for s, _ in srcs if s != ref and s in index][:num_neighbors]
        return
    log.info("no pair.txt; choosing neighbours from the camera geometry")
    set_neighbors_from_cameras(views, num_neighbors)


def load_mvsnet_scene(
    root: str | Path,
    depth_format: DepthFormat = "auto",
    num_depth: int = DEFAULT_NUM_DEPTH,
    interval_scale: float = 1.0,
    cam_dir: str | Path | None = None,
    image_dir: str | Path | None = None,
    pair_path: str | Path | None = None,
    num_neighbors: int = 10,
) -> Scene:
    """Load an MVSNet-layout scene folder.

    ``root/cams/NNNNNNNN_cam.txt`` define the views (sorted by id); images are ``root/images/NNNNNNNN.*``;
    neighbours come from ``root/pair.txt`` (ids mapped to view indices), or, without one, from the
    camera geometry (:func:`mvsformerpp.io.viewselect.neighbors_from_cameras`); ``cams/pair.txt`` is
    used when there is no ``root/pair.txt``. ``cam_dir``,
    ``image_dir`` and ``pair_path`` override the default locations (absolute or relative to ``root``).
    ``interval_scale`` stretches each depth range about its minimum, as the official loaders do with
    the depth interval (1.06 in the MVSFormer++ test configurations).
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError("not a folder (expected an MVSNet scene with images/, cams/ and pair.txt)", root)
    cam_dir = root / (cam_dir or "cams")
    image_dir = root / (image_dir or "images")
    if pair_path is None and not (root / "pair.txt").is_file() and (cam_dir / "pair.txt").is_file():
        pair_path = cam_dir / "pair.txt"  # some releases keep it with the cams
    pair_path = root / (pair_path or "pair.txt")
    if not cam_dir.is_dir():
        raise InputError(f"no camera folder {cam_dir.name}/ (expected NNNNNNNN_cam.txt files)", root)
    cams = cam_files(cam_dir)
    if not cams:
        raise InputError("the camera folder holds no NNNNNNNN_cam.txt files: the scene is empty", cam_dir)
    if not image_dir.is_dir():
        raise InputError(f"no image folder {image_dir.name}/", root)
    views: list[View] = []
    scales: list[float] = []
    for vid, cam_path in cams.items():
        stem = f"{vid:08d}"
        img = find_image(image_dir, stem) or find_image(image_dir, str(vid))
        if img is None:
            raise InputError(f"no image for camera {cam_path.name} (looked for {stem}.jpg/.png/...)", image_dir)
        views.append(view_from_cam(stem, cam_path, img, depth_format, num_depth, interval_scale, scales))
    report_scaling(root, scales)
    set_neighbors(views, list(cams), pair_path, num_neighbors)
    for view in views:  # ground truth beside the scene, as `mvsformerpp synth` writes it
        gt, mask = root / "depth_gt" / f"{view.name}.pfm", root / "masks" / f"{view.name}.png"
        view.depth_gt_path = gt if gt.is_file() else None
        view.mask_path = mask if mask.is_file() else None
    return Scene(views=views, root=root, source_format="mvsnet")


def write_mvsnet_scene(
    scene: Scene,
    root: str | Path,
    copy_images: bool = True,
    num_depth: int = DEFAULT_NUM_DEPTH,
    scores: list[list[float]] | None = None,
) -> Path:
    """Write ``scene`` as ``root/{images,cams}/`` + ``root/pair.txt``; view i gets id i.

    Images are copied byte for byte (keeping their suffix) unless ``copy_images`` is False. The Scene
    keeps neighbour order, not scores: pair.txt gets ``scores`` when given, else the rank-based
    scores M, M-1, ..., 1 (higher is better, as in MVSNet pair files).
    """
    root = Path(root)
    if not scene.views:
        raise InputError("the scene has no views; nothing to write", root)
    (root / "cams").mkdir(parents=True, exist_ok=True)
    pairs: Pairs = {}
    for i, v in enumerate(scene.views):
        cam = MVSNetCam(extrinsic=v.extrinsic, K=v.K, depth_min=v.depth_min, depth_max=v.depth_max)
        write_cam(root / "cams" / f"{i:08d}_cam.txt", cam, num_depth)
        if copy_images:
            dst = root / "images" / f"{i:08d}{v.image_path.suffix.lower()}"
            if v.image_path.resolve() != dst.resolve():
                with atomic_open(dst, "wb") as f, open(v.image_path, "rb") as src:
                    shutil.copyfileobj(src, f)
        m = len(v.neighbors)
        sc = scores[i] if scores is not None else [float(m - r) for r in range(m)]
        pairs[i] = list(zip(v.neighbors, sc))
    write_pair(root / "pair.txt", pairs)
    return root
