"""Middlebury multi-view stereo ``*_par.txt`` (Seitz et al., CVPR 2006): temple, dino and their rings.

Format: a first line with the number of images, then one line per image::

    imgname.png k11 k12 k13 k21 k22 k23 k31 k32 k33 r11 r12 r13 r21 r22 r23 r31 r32 r33 t1 t2 t3

with projection K [R | t] (world-to-camera), image origin top-left. Photos sit beside the file.

The file has no depth range. Heuristic, in order:
1. Bounding box: the data sets' README states the object's tight bounding box as two lines
   ``(x y z)``; when a README beside the par file gives one, each view's range is the min/max
   z-depth of the box's 8 corners (the box is convex, so this bounds every object point).
2. Camera geometry: otherwise the scene centre X is the least-squares point closest to all optical
   axes, and the object is assumed to fit in the sphere about X that the narrowest image half-angle
   subtends: r = z_X * tan(atan(min(W, H) / 2 / f)) = z_X * min(W, H) / (2 f). The range is
   [z_X - r, z_X + r] (clamped to stay positive). With parallel axes there is no range (None).
Neighbours: the MVSNet angle score at the scene centre (:func:`viewselect.neighbors_from_cameras`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.images import image_size
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.io.viewselect import point_closest_to_axes, set_neighbors_from_cameras
from mvsformerpp.utils.atomic import atomic_open


def temple_dir() -> Path:
    """Folder of the temple the package ships (``assets/templeSparseRing``): its photos, ``templeSR_par.txt`` and
    README.txt with the data's attribution."""
    return Path(__file__).resolve().parent.parent / "assets" / "templeSparseRing"


_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_BOX_RE = re.compile(rf"\(\s*({_NUM})\s*[, ]\s*({_NUM})\s*[, ]\s*({_NUM})\s*\)")


def read_par(path: str | Path) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """Read a par file as ``[(name, K [3,3], R [3,3], t [3]), ...]`` in file order."""
    path = Path(path)
    try:
        lines = [ln.split() for ln in path.read_bytes().decode("utf-8-sig").splitlines()]
    except FileNotFoundError as e:
        raise InputError("camera file not found", path) from e
    except (OSError, UnicodeDecodeError) as e:
        raise FormatError("cannot read the Middlebury par file as text", path) from e
    lines = [ln for ln in lines if ln]
    if not lines or len(lines[0]) != 1 or not re.fullmatch(r"[0-9]+", lines[0][0]):
        raise FormatError("a Middlebury par file starts with the number of images on its own line", path)
    count = int(lines[0][0])
    if count != len(lines) - 1:
        raise FormatError(f"the header says {count} images but {len(lines) - 1} camera lines follow", path)
    out = []
    for n, tok in enumerate(lines[1:], start=2):
        if len(tok) != 22:
            found = f"a name and {len(tok) - 1} numbers" if tok else "an empty line"
            raise FormatError(f"line {n}: expected an image name and 21 numbers (K, R, t), found {found}", path)
        try:
            vals = np.array([float(x) for x in tok[1:]])
        except ValueError as e:
            raise FormatError(f"line {n}: {e}", path) from e
        if not np.all(np.isfinite(vals)):
            raise FormatError(f"line {n}: non-finite numbers", path)
        K, R, t = vals[:9].reshape(3, 3), vals[9:18].reshape(3, 3), vals[18:]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
            raise FormatError(f"line {n}: R of {tok[0]} is not a rotation matrix", path)
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
            raise FormatError(f"line {n}: K of {tok[0]} is not an intrinsic matrix", path)
        out.append((tok[0], K, R, t))
    return out


def write_par(path: str | Path, cams: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]) -> None:
    """Write a par file atomically (inverse of :func:`read_par`)."""

    with atomic_open(path, "w") as f:
        f.write(f"{len(cams)}\n")
        for name, K, R, t in cams:
            nums = np.concatenate([np.ravel(K), np.ravel(R), np.ravel(t)])
            f.write(name + " " + " ".join(repr(float(v)) for v in nums) + "\n")


def read_bounding_box(folder: str | Path) -> np.ndarray | None:
    """The ``[2, 3]`` (min corner, max corner) bounding box from a README in ``folder``, or None."""
    for readme in sorted(Path(folder).glob("README*")):
        try:
            text = readme.read_text(errors="replace")
        except OSError:
            continue
        if "bounding box" not in text.lower():
            continue
        after = text[text.lower().index("bounding box"):]
        boxes = _BOX_RE.findall(after)
        if len(boxes) >= 2:
            box = np.array(boxes[:2], dtype=np.float64)
            lo, hi = np.minimum(box[0], box[1]), np.maximum(box[0], box[1])
            if np.all(hi > lo):
                return np.stack([lo, hi])
    return None


def box_depth_range(box: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[float, float] | None:
    """Min/max z-depth of the 8 corners of an axis-aligned box; None if a corner is not in front."""
    corners = np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    z = (corners @ R.T + t)[:, 2]
    if z.min() <= 0:
        return None
    return float(z.min()), float(z.max())


def geometric_depth_ranges(views: list[View]) -> list[tuple[float, float] | None]:
    """Depth ranges from the camera geometry alone (heuristic 2 of the module docstring)."""
    centers = np.stack([v.center for v in views])
    dirs = np.stack([v.R[2] for v in views])
    X = point_closest_to_axes(centers, dirs)
    if X is None:
        return [None] * len(views)
    out = []
    for v in views:
        zx = float((v.R @ X + v.t)[2])
        r = zx * min(v.width, v.height) / (2.0 * max(v.K[0, 0], v.K[1, 1]))
        out.append((max(zx - r, 0.05 * zx), zx + r))
    return out


def find_par_file(path: str | Path) -> Path | None:
    """The par file at ``path`` or the single ``*_par.txt`` in the folder ``path``; None if there is none."""
    path = Path(path)
    if path.is_file():
        return path if path.name.endswith("_par.txt") else None
    found = sorted(path.glob("*_par.txt")) if path.is_dir() else []
    return found[0] if found else None


def load_middlebury_scene(path: str | Path, num_neighbors: int = 10) -> Scene:
    """Load a Middlebury par file (or a folder holding one) and the photos beside it."""
    path = Path(path)
    par = find_par_file(path)
    if par is None:
        raise InputError("no Middlebury *_par.txt camera file here", path)
    folder = par.parent
    views = []
    for name, K, R, t in read_par(par):
        img = folder / name
        if not img.is_file():
            raise InputError(f"photo {name} listed in {par.name} is missing", img)
        w, h = image_size(img)
        views.append(View(name=Path(name).stem, image_path=img, width=w, height=h, K=K, R=R, t=t))
    if not views:
        raise InputError("the par file lists no images: the scene is empty", par)
    box = read_bounding_box(folder)
    ranges = [box_depth_range(box, v.R, v.t) for v in views] if box is not None else [None] * len(views)
    if any(r is None for r in ranges):
        ranges = geometric_depth_ranges(views)
    for v, r in zip(views, ranges):
        if r is not None:
            v.depth_min, v.depth_max = r
    set_neighbors_from_cameras(views, num_neighbors)
    return Scene(views=views, root=par, source_format="middlebury")
