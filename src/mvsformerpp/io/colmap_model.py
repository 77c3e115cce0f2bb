"""COLMAP sparse models: ``cameras``, ``images``, ``points3D`` in text (``.txt``) and binary (``.bin``).

Conventions (COLMAP's own, kept as is):
* Images store the world-to-camera pose as a unit quaternion ``(qw, qx, qy, qz)`` (Hamilton) and a
  translation: X_cam = R(q) X_world + t.
* A 2-D observation without a triangulated point has ``point3D_id = -1``.
* Camera parameters follow the model's parameter list (``CAMERA_MODELS``); the principal point is in
  COLMAP's pixel convention (centre of the top-left pixel at (0.5, 0.5)).

Binary layout (little-endian), as COLMAP writes it:
* cameras.bin: u64 count; per camera i32 id, i32 model_id, u64 width, u64 height, f64 params[n].
* images.bin: u64 count; per image u32 id, f64 qw qx qy qz, f64 tx ty tz, u32 camera_id,
  NUL-terminated name, u64 num_points2D, then per point f64 x, f64 y, i64 point3D_id.
* points3D.bin: u64 count; per point u64 id, f64 x y z, u8 r g b, f64 error, u64 track length,
  then per track element i32 image_id, i32 point2D_idx.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.utils.atomic import atomic_open

# model name -> (model id, parameter names), as COLMAP defines them (src/colmap/sensor/models.h).
CAMERA_MODELS: dict[str, tuple[int, tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": (0, ("f", "cx", "cy")),
    "PINHOLE": (1, ("fx", "fy", "cx", "cy")),
    "SIMPLE_RADIAL": (2, ("f", "cx", "cy", "k")),
    "RADIAL": (3, ("f", "cx", "cy", "k1", "k2")),
    "OPENCV": (4, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    "OPENCV_FISHEYE": (5, ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
    "FULL_OPENCV": (6, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")),
    "FOV": (7, ("fx", "fy", "cx", "cy", "omega")),
    "SIMPLE_RADIAL_FISHEYE": (8, ("f", "cx", "cy", "k")),
    "RADIAL_FISHEYE": (9, ("f", "cx", "cy", "k1", "k2")),
    "THIN_PRISM_FISHEYE": (10, ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1")),
    "RAD_TAN_THIN_PRISM_FISHEYE": (
        11, ("fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3")),
    "SIMPLE_DIVISION": (12, ("f", "cx", "cy", "k")),
    "DIVISION": (13, ("fx", "fy", "cx", "cy", "k")),
    "SIMPLE_FISHEYE": (14, ("f", "cx", "cy")),
    "FISHEYE": (15, ("fx", "fy", "cx", "cy")),
    "EUCM": (16, ("fx", "fy", "cx", "cy", "alpha", "beta")),
}
MODEL_BY_ID = {mid: name for name, (mid, _) in CAMERA_MODELS.items()}
# Models that are pinhole projections (no distortion) whatever their parameters.
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
# Fisheye projections are never pinhole, even with all distortion terms zero.
FISHEYE_MODELS = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE",
                  "RAD_TAN_THIN_PRISM_FISHEYE", "SIMPLE_FISHEYE", "FISHEYE", "FOV", "EUCM")


@dataclass
class ColmapCamera:
    id: int
    model: str
    width: int
    height: int
    params: np.ndarray  # [n] float64, in the order of CAMERA_MODELS[model]

    @property
    def is_pinhole(self) -> bool:
        """True when the model projects as a pinhole: a pinhole model, or a perspective model with zero distortion."""
        if self.model in PINHOLE_MODELS:
            return True
        if self.model in FISHEYE_MODELS:
            return False
        n_focal = 1 if CAMERA_MODELS[self.model][1][0] == "f" else 2
        return bool(np.all(self.params[n_focal + 2:] == 0))

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsics from the focal length(s) and principal point (distortion ignored)."""
        p = self.params
        if CAMERA_MODELS[self.model][1][0] == "f":
            fx = fy = p[0]
            cx, cy = p[1], p[2]
        else:
            fx, fy, cx, cy = p[:4]
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


@dataclass
class ColmapImage:
    id: int
    qvec: np.ndarray  # [4] (qw, qx, qy, qz), world -> camera
    tvec: np.ndarray  # [3]
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # [N,2] float64
    point3D_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # [N] int64, -1 = none

    @property
    def R(self) -> np.ndarray:
        return qvec_to_rotmat(self.qvec)


@dataclass
class ColmapPoint3D:
    id: int
    xyz: np.ndarray  # [3]
    rgb: np.ndarray  # [3] uint8
    error: float
    image_ids: np.ndarray  # [L] int64
    point2D_idxs: np.ndarray  # [L] int64


@dataclass
class ColmapModel:
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points3D: dict[int, ColmapPoint3D]


def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of the quaternion ``(w, x, y, z)`` (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` with w >= 0 of a rotation matrix (eigenvector method)."""
    R = np.asarray(R, dtype=np.float64)
    (xx, yx, zx), (xy, yy, zy), (xz, yz, zz) = R
    Kq = np.array([
        [xx - yy - zz, 0, 0, 0],
        [yx + xy, yy - xx - zz, 0, 0],
        [zx + xz, zy + yz, zz - xx - yy, 0],
        [yz - zy, zx - xz, xy - yx, xx + yy + zz],
    ]) / 3.0
    _, vecs = np.linalg.eigh(Kq)
    q = vecs[[3, 0, 1, 2], -1]
    return -q if q[0] < 0 else q


# ------------------------------------------------------------------------------------------- text


def _text_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except OSError as e:
        raise FormatError(f"cannot read ({e.strerror})", path) from e
    except UnicodeDecodeError as e:
        raise FormatError("not a COLMAP text file (not UTF-8 text)", path) from e
    return [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]


def _parse_number(tok: str, path: Path, lineno: int, kind: type = float):
    """``kind(tok)``, finite (floats) or within int64 (ints); else FormatError naming the line."""
    try:
        v = kind(tok)
    except ValueError as e:
        raise FormatError(f"line {lineno}: {tok!r} is not a valid {kind.__name__}", path) from e
    if kind is float and not np.isfinite(v):
        raise FormatError(f"line {lineno}: non-finite number {tok!r}", path)
    if kind is int and not -(2**63) <= v < 2**63:
        raise FormatError(f"line {lineno}: integer {tok!r} is out of range", path)
    return v


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _floats_fast(tokens: list[str], path: Path, lineno: int) -> np.ndarray:
    """Many floats at once (numpy parses); per-token parsing only to name a bad token."""
    try:
        arr = np.array(tokens, dtype=np.float64)
    except (ValueError, OverflowError):
        arr = np.array([_parse_number(t, path, lineno) for t in tokens], dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise FormatError(f"line {lineno}: non-finite number", path)
    return arr


def _ints_fast(tokens: list[str], path: Path, lineno: int) -> np.ndarray:
    try:
        return np.array([int(t) for t in tokens], dtype=np.int64)
    except (ValueError, OverflowError):
        return np.array([_parse_number(t, path, lineno, int) for t in tokens], dtype=np.int64)


def _camera(cid: int, model: str, width: int, height: int, params: list[float], path: Path, where: str):
    if model not in CAMERA_MODELS:
        raise FormatError(f"{where}: unknown camera model {model!r} (known: {', '.join(CAMERA_MODELS)})", path)
    need = len(CAMERA_MODELS[model][1])
    if len(params) != need:
        raise FormatError(f"{where}: camera model {model} takes {need} parameters, found {len(params)}", path)
    params = np.asarray(params, dtype=np.float64)
    if not np.all(np.isfinite(params)):
        raise FormatError(f"{where}: camera {cid} has non-finite parameters", path)
    if width <= 0 or height <= 0:
        raise FormatError(f"{where}: camera {cid} has image size {width}x{height}", path)
    return ColmapCamera(cid, model, int(width), int(height), params)


def read_cameras_text(path: str | Path) -> dict[int, ColmapCamera]:
    path = Path(path)
    cams = {}
    for n, ln in _text_lines(path):
        if not ln or ln.startswith("#"):
            continue
        tok = ln.split()
        if len(tok) < 4:
            raise FormatError(f"line {n}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'", path)
        cid = _parse_number(tok[0], path, n, int)
        params = [_parse_number(t, path, n) for t in tok[4:]]
        width, height = _parse_number(tok[2], path, n, int), _parse_number(tok[3], path, n, int)
        cams[cid] = _camera(cid, tok[1], width, height, params, path, f"line {n}")
    return cams


def read_images_text(path: str | Path) -> dict[int, ColmapImage]:
    path = Path(path)
    lines = [(n, ln) for n, ln in _text_lines(path) if not ln.startswith("#")]
    images = {}
    i = 0
    while i < len(lines):
        n, ln = lines[i]
        if not ln:  # blank lines between entries (COLMAP writes an empty 2-D line for images without points)
            i += 1
            continue
        tok = ln.split(maxsplit=9)
        if len(tok) < 10:
            raise FormatError(f"line {n}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'", path)
        iid = _parse_number(tok[0], path, n, int)
        q = np.array([_parse_number(t, path, n) for t in tok[1:5]])
        if np.linalg.norm(q) < 1e-12:
            raise FormatError(f"line {n}: image {iid} has a zero quaternion", path)
        t = np.array([_parse_number(t, path, n) for t in tok[5:8]])
        cam_id = _parse_number(tok[8], path, n, int)
        pts = lines[i + 1][1].split() if i + 1 < len(lines) else []
        pn = lines[i + 1][0] if i + 1 < len(lines) else n
        if len(pts) >= 10 and not _is_number(pts[-1]):
            raise FormatError(f"line {pn}: expected the 2-D points of image {iid} ({tok[9]}): 'X Y POINT3D_ID' "
                              "triples, or an empty line when it has none; found what looks like the next image's "
                              "line (every image takes two lines)", path)
        if len(pts) % 3:
            raise FormatError(f"line {pn}: 2-D points come as 'X Y POINT3D_ID' triples", path)
        xys = _floats_fast(pts[0::3] + pts[1::3], path, pn).reshape(2, -1).T
        ids = _ints_fast(pts[2::3], path, pn)
        images[iid] = ColmapImage(iid, q, t, cam_id, tok[9], np.ascontiguousarray(xys), ids)
        i += 2
    return images


def read_points3D_text(path: str | Path) -> dict[int, ColmapPoint3D]:
    path = Path(path)
    pts = {}
    for n, ln in _text_lines(path):
        if not ln or ln.startswith("#"):
            continue
        tok = ln.split()
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise FormatError(f"line {n}: expected 'POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)...'", path)
        pid = _parse_number(tok[0], path, n, int)
        xyz = np.array([_parse_number(t, path, n) for t in tok[1:4]])
        rgb = np.array([_parse_number(t, path, n, int) for t in tok[4:7]])
        if np.any((rgb < 0) | (rgb > 255)):
            raise FormatError(f"line {n}: colour {rgb.tolist()} is outside 0..255", path)
        track = _ints_fast(tok[8:], path, n).reshape(-1, 2)
        pts[pid] = ColmapPoint3D(pid, xyz, rgb.astype(np.uint8), _parse_number(tok[7], path, n), track[:, 0].copy(),
                                 track[:, 1].copy())
    return pts


def write_cameras_text(path: str | Path, cameras: dict[int, ColmapCamera]) -> None:
    with atomic_open(path, "w") as f:
        f.write("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n")
        f.write(f"# Number of cameras: {len(cameras)}\n")
        for c in cameras.values():
            f.write(" ".join([str(c.id), c.model, str(c.width), str(c.height)] + [repr(float(p)) for p in c.params]))
            f.write("\n")


def write_images_text(path: str | Path, images: dict[int, ColmapImage]) -> None:
    with atomic_open(path, "w") as f:
        f.write("# Image list with two lines of data per image:\n"
                "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
                "#   POINTS2D[] as (X, Y, POINT3D_ID)\n")
        f.write(f"# Number of images: {len(images)}\n")
        for im in images.values():
            head = [str(im.id)] + [repr(float(v)) for v in (*im.qvec, *im.tvec)] + [str(im.camera_id), im.name]
            f.write(" ".join(head) + "\n")
            f.write(" ".join(f"{float(x)!r} {float(y)!r} {int(p)}" for (x, y), p in zip(im.xys, im.point3D_ids)))
            f.write("\n")


def write_points3D_text(path: str | Path, points: dict[int, ColmapPoint3D]) -> None:
    with atomic_open(path, "w") as f:
        f.write("# 3D point list with one line of data per point:\n"
                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n")
        f.write(f"# Number of points: {len(points)}\n")
        for p in points.values():
            parts = [str(p.id)] + [repr(float(v)) for v in p.xyz] + [str(int(c)) for c in p.rgb]
            parts.append(repr(float(p.error)))
            parts += [f"{int(i)} {int(j)}" for i, j in zip(p.image_ids, p.point2D_idxs)]
            f.write(" ".join(parts) + "\n")


# ----------------------------------------------------------------------------------------- binary


class _Reader:
    """Bounds-checked little-endian reads from a byte buffer; running out raises FormatError."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as e:
            raise FormatError(f"cannot read ({e.strerror})", path) from e
        self.pos = 0

    def take(self, n: int, what: str) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise FormatError(f"file is truncated or corrupt (while reading {what} at byte {self.pos})", self.path)
        self.pos += n
        return self.data[self.pos - n:self.pos]

    def unpack(self, fmt: str, what: str) -> tuple:
        return struct.unpack("<" + fmt, self.take(struct.calcsize("<" + fmt), what))

    def array(self, dtype: np.dtype, count: int, what: str) -> np.ndarray:
        dtype = np.dtype(dtype)
        if count > len(self.data):  # a count larger than the file is corrupt, not a request for memory
            raise FormatError(f"file is truncated or corrupt ({what}: count {count})", self.path)
        return np.frombuffer(self.take(dtype.itemsize * count, what), dtype=dtype, count=count)

    def cstring(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise FormatError(f"file is truncated or corrupt (unterminated {what})", self.path)
        raw = self.take(end - self.pos + 1, what)[:-1]
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError as e:
            raise FormatError(f"{what} is not valid UTF-8", self.path) from e

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise FormatError(f"{len(self.data) - self.pos} unexpected bytes after the last record", self.path)


def read_cameras_binary(path: str | Path) -> dict[int, ColmapCamera]:
    r = _Reader(Path(path))
    (count,) = r.unpack("Q", "the camera count")
    cams = {}
    for k in range(count):
        cid, mid, w, h = r.unpack("iiQQ", f"camera {k}")
        if mid not in MODEL_BY_ID:
            raise FormatError(f"camera {cid}: unknown camera model id {mid}", r.path)
        model = MODEL_BY_ID[mid]
        params = r.array("<f8", len(CAMERA_MODELS[model][1]), f"camera {cid} parameters").astype(np.float64)
        cams[cid] = _camera(cid, model, w, h, list(params), r.path, f"camera {cid}")
    r.finish()
    return cams


_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
_TRACK = np.dtype([("image_id", "<i4"), ("idx", "<i4")])


def read_images_binary(path: str | Path) -> dict[int, ColmapImage]:
    r = _Reader(Path(path))
    (count,) = r.unpack("Q", "the image count")
    images = {}
    for k in range(count):
        iid, qw, qx, qy, qz, tx, ty, tz, cam_id = r.unpack("I7dI", f"image {k}")
        vals = np.array([qw, qx, qy, qz, tx, ty, tz])
        if not np.all(np.isfinite(vals)) or np.linalg.norm(vals[:4]) < 1e-12:
            raise FormatError(f"image {iid}: non-finite or zero pose", r.path)
        name = r.cstring(f"image {iid} name")
        (n2d,) = r.unpack("Q", f"image {iid} point count")
        pts = r.array(_POINT2D, n2d, f"image {iid} points")
        xys = np.stack([pts["x"], pts["y"]], axis=1).astype(np.float64)
        images[iid] = ColmapImage(iid, vals[:4], vals[4:], cam_id, name, xys, pts["id"].astype(np.int64))
    r.finish()
    return images


def read_points3D_binary(path: str | Path) -> dict[int, ColmapPoint3D]:
    r = _Reader(Path(path))
    (count,) = r.unpack("Q", "the point count")
    pts = {}
    for k in range(count):
        pid, x, y, z, cr, cg, cb, err, length = r.unpack("Q3d3BdQ", f"point {k}")
        xyz = np.array([x, y, z])
        if not np.all(np.isfinite(xyz)):
            raise FormatError(f"point {pid}: non-finite coordinates", r.path)
        track = r.array(_TRACK, length, f"point {pid} track")
        pts[pid] = ColmapPoint3D(pid, xyz, np.array([cr, cg, cb], np.uint8), float(err),
                                 track["image_id"].astype(np.int64), track["idx"].astype(np.int64))
    r.finish()
    return pts


def write_cameras_binary(path: str | Path, cameras: dict[int, ColmapCamera]) -> None:
    with atomic_open(path, "wb") as f:
        f.write(struct.pack("<Q", len(cameras)))
        for c in cameras.values():
            f.write(struct.pack("<iiQQ", c.id, CAMERA_MODELS[c.model][0], c.width, c.height))
            f.write(np.asarray(c.params, "<f8").tobytes())


def write_images_binary(path: str | Path, images: dict[int, ColmapImage]) -> None:
    with atomic_open(path, "wb") as f:
        f.write(struct.pack("<Q", len(images)))
        for im in images.values():
            f.write(struct.pack("<I7dI", im.id, *np.asarray(im.qvec, float), *np.asarray(im.tvec, float),
                                im.camera_id))
            f.write(im.name.encode("utf-8") + b"\0")
            pts = np.zeros(len(im.point3D_ids), _POINT2D)
            pts["x"], pts["y"], pts["id"] = im.xys[:, 0], im.xys[:, 1], im.point3D_ids
            f.write(struct.pack("<Q", len(pts)) + pts.tobytes())


def write_points3D_binary(path: str | Path, points: dict[int, ColmapPoint3D]) -> None:
    with atomic_open(path, "wb") as f:
        f.write(struct.pack("<Q", len(points)))
        for p in points.values():
            f.write(struct.pack("<Q3d3BdQ", p.id, *np.asarray(p.xyz, float), *(int(c) for c in p.rgb),
                                float(p.error), len(p.image_ids)))
            track = np.zeros(len(p.image_ids), _TRACK)
            track["image_id"], track["idx"] = p.image_ids, p.point2D_idxs
            f.write(track.tobytes())


# ------------------------------------------------------------------------------------------ model

_READERS = {
    ".txt": (read_cameras_text, read_images_text, read_points3D_text),
    ".bin": (read_cameras_binary, read_images_binary, read_points3D_binary),
}
_WRITERS = {
    ".txt": (write_cameras_text, write_images_text, write_points3D_text),
    ".bin": (write_cameras_binary, write_images_binary, write_points3D_binary),
}


def model_extension(path: str | Path) -> str | None:
    """``".bin"`` or ``".txt"`` if ``path`` holds a complete model (binary preferred), else None."""
    path = Path(path)
    for ext in (".bin", ".txt"):
        if all((path / f"{n}{ext}").is_file() for n in ("cameras", "images", "points3D")):
            return ext
    return None


def read_model(path: str | Path, ext: str | None = None) -> ColmapModel:
    """Read ``cameras``, ``images`` and ``points3D`` from the folder ``path`` (binary preferred)."""
    path = Path(path)
    ext = ext or model_extension(path)
    if ext is None:
        raise InputError("no COLMAP model here (looked for cameras/images/points3D .bin or .txt)", path)
    rc, ri, rp = _READERS[ext]
    model = ColmapModel(rc(path / f"cameras{ext}"), ri(path / f"images{ext}"), rp(path / f"points3D{ext}"))
    for im in model.images.values():
        if im.camera_id not in model.cameras:
            raise FormatError(f"image {im.id} ({im.name}) uses camera {im.camera_id}, which is not defined",
                              path / f"images{ext}")
    return model


def write_model(model: ColmapModel, path: str | Path, ext: str = ".bin") -> Path:
    """Write the three model files into the folder ``path`` (``ext`` is ``".bin"`` or ``".txt"``)."""
    if ext not in _WRITERS:
        raise ValueError(f"ext must be '.bin' or '.txt', got {ext!r}")
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    wc, wi, wp = _WRITERS[ext]
    wc(path / f"cameras{ext}", model.cameras)
    wi(path / f"images{ext}", model.images)
    wp(path / f"points3D{ext}", model.points3D)
    return path
