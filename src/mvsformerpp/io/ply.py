"""PLY point clouds: binary little-endian writer, reader for ascii and binary (either endianness).

Only the ``vertex`` element is returned by the reader; other elements (faces, ...) are skipped
when they follow the vertices. Points are float coordinates ``x, y, z`` plus optional
``red, green, blue`` (uint8), ``nx, ny, nz`` and any other scalar properties.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError
from mvsformerpp.utils.atomic import atomic_open
from mvsformerpp.utils.file_kinds import POINT_CLOUD, FileKind

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NUMPY_TO_PLY = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
                 "u4": "uint", "f4": "float", "f8": "double"}


def vertex_records(
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    extra: dict[str, np.ndarray] | None = None,
) -> np.ndarray:
    """Points as a structured little-endian array in PLY vertex order (see :func:`write_ply`)."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must be [N,3], got {xyz.shape}")
    n = len(xyz)
    fields: list[tuple[str, np.dtype, np.ndarray]] = [
        (name, np.dtype("<f4"), xyz[:, i]) for i, name in enumerate("xyz")
    ]
    if normals is not None:
        normals = np.asarray(normals)
        fields += [(name, np.dtype("<f4"), normals[:, i]) for i, name in enumerate(("nx", "ny", "nz"))]
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != (n, 3):
            raise ValueError(f"rgb must be [N,3] like xyz, got {rgb.shape}")
        if rgb.dtype != np.uint8:
            rgb = np.clip(np.round(rgb.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
        fields += [(name, np.dtype("u1"), rgb[:, i]) for i, name in enumerate(("red", "green", "blue"))]
    for name, values in (extra or {}).items():
        values = np.asarray(values)
        if values.shape != (n,):
            raise ValueError(f"extra field {name!r} must be [N], got {values.shape}")
        fields.append((name, values.dtype.newbyteorder("<"), values))
    data = np.empty(n, dtype=np.dtype([(name, dt) for name, dt, _ in fields]))
    for name, _, values in fields:
        data[name] = values
    return data


def _header(record: np.dtype, count: str, kind: FileKind) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0", kind.marker.decode("ascii").rstrip("\n"),
             f"element vertex {count}"]
    lines += [f"property {_NUMPY_TO_PLY[record[name].str[1:]]} {name}" for name in record.names]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply(
    path: str | Path,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    extra: dict[str, np.ndarray] | None = None,
    faces: np.ndarray | None = None,
    kind: FileKind = POINT_CLOUD,
) -> None:
    """Write a binary little-endian PLY point cloud (or mesh, with ``faces``) atomically.

    xyz: [N,3] (stored as float32); rgb: [N,3] uint8 or floats in [0,1]; normals: [N,3];
    extra: name -> [N] scalar arrays (e.g. ``confidence``), stored with their own dtype;
    faces: [M,3] vertex indices of triangles (a ``face`` element with ``vertex_indices`` lists);
    kind: what the file is (:mod:`mvsformerpp.utils.file_kinds`), named in its header so that only a
    command writing this kind replaces it.
    """
    data = vertex_records(xyz, rgb, normals, extra)
    header = _header(data.dtype, str(len(data)), kind)
    tris = None
    if faces is not None:
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must be [M,3], got {faces.shape}")
        tris = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        tris["n"], tris["v"] = 3, faces
        face_lines = f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
        header = header.replace(b"end_header\n", face_lines.encode("ascii"))
    with atomic_open(path, "wb") as f:
        f.write(header)
        f.write(data.tobytes())
        if tris is not None:
            f.write(tris.tobytes())


# Width of the vertex count in a streamed header: room for any count, patched in place at the end.
_COUNT_WIDTH = 20


class PlyStreamWriter:
    """A binary PLY written piece by piece, so the points never need to be in memory together.

    Use as a context manager: ``with PlyStreamWriter(path) as w: w.write(xyz, rgb)``. Every piece
    must have the same fields. The header announces the vertex count right-aligned in a fixed-width
    field (PLY readers split header lines on whitespace), patched in place when the writer closes;
    the file is written under a temporary name and renamed only on success
    (:mod:`mvsformerpp.utils.atomic`), so an error leaves no partial cloud behind.
    """

    def __init__(self, path: str | Path, kind: FileKind = POINT_CLOUD):
        self.path = Path(path)
        self.kind = kind
        self.count = 0
        self._record: np.dtype | None = None
        self._ctx = None
        self._file = None
        self._count_offset = 0

    def __enter__(self) -> PlyStreamWriter:
        self._ctx = atomic_open(self.path, "wb")
        self._file = self._ctx.__enter__()
        return self

    def _start(self, record: np.dtype) -> None:
        self._record = record
        header = _header(record, " " * _COUNT_WIDTH, self.kind)
        self._count_offset = header.index(b"element vertex ") + len(b"element vertex ")
        self._file.write(header)

    def write(self, xyz: np.ndarray, rgb: np.ndarray | None = None, normals: np.ndarray | None = None,
              extra: dict[str, np.ndarray] | None = None) -> None:
        """Append points (the arguments of :func:`write_ply`)."""
        data = vertex_records(xyz, rgb, normals, extra)
        if self._record is None:
            self._start(data.dtype)
        elif data.dtype != self._record:
            raise ValueError(f"PLY piece has fields {data.dtype.names}, the file {self._record.names}")
        self._file.write(data.tobytes())
        self.count += len(data)

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                if self._record is None:  # nothing written: an empty cloud of xyz + rgb
                    self._start(vertex_records(np.zeros((0, 3)), np.zeros((0, 3), np.uint8)).dtype)
                self._file.seek(self._count_offset)
                self._file.write(f"{self.count:>{_COUNT_WIDTH}d}".encode("ascii"))
                self._file.seek(0, 2)
            except BaseException as e:  # the temporary file goes too, and the error names the cloud
                self._ctx.__exit__(type(e), e, e.__traceback__)
                raise
        return self._ctx.__exit__(exc_type, exc, tb)


def _element_count(text: str, name: str, path: Path) -> int:
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 0:
        raise FormatError(f"PLY element {name!r} has count {text!r}: expected a whole number >= 0", path)
    return count


def ply_vertex_count(path: str | Path) -> int:
    """The vertex count a PLY header announces (reads the header only)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise FormatError(f"cannot read PLY file ({e.strerror})", path) from e
    for line in head.split(b"\n"):
        parts = line.split()
        if parts[:2] == [b"element", b"vertex"] and len(parts) == 3:
            return _element_count(parts[2].decode("ascii", errors="replace"), "vertex", path)
        if parts[:1] == [b"end_header"]:
            break
    raise FormatError("PLY header has no 'element vertex N' line", path)


def read_ply(path: str | Path) -> dict[str, np.ndarray]:
    """Read the vertex element of a PLY file: a dict of property name -> [N] array.

    Use :func:`ply_points` for the [N,3] coordinates.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise FormatError(f"cannot read PLY file ({e.strerror})", path) from e
    if not raw.startswith(b"ply"):
        raise FormatError("not a PLY file (it does not start with 'ply')", path)
    end = raw.find(b"end_header")
    if end < 0:
        raise FormatError("PLY header has no 'end_header' line", path)
    body_start = raw.index(b"\n", end) + 1
    fmt, elements = _parse_header(raw[:end].decode("ascii", errors="replace").splitlines(), path)
    vertex_idx = next((i for i, e in enumerate(elements) if e[0] == "vertex"), None)
    if vertex_idx is None:
        raise FormatError("PLY file has no 'vertex' element", path)
    if fmt == "ascii":
        return _read_ascii(raw[body_start:], elements, vertex_idx, path)
    order = "<" if fmt == "binary_little_endian" else ">"
    offset = body_start
    for i, (_name, count, props) in enumerate(elements):
        if any(p[1] is not None for p in props):
            if i < vertex_idx:
                raise FormatError("PLY elements with list properties before 'vertex' are not supported", path)
            break
        dt = np.dtype([(p[0], order + _PLY_TYPES[p[2]]) for p in props])
        if i == vertex_idx:
            if len(raw) - offset < dt.itemsize * count:
                raise FormatError(f"PLY file is truncated: {count} vertices announced", path)
            extra = len(raw) - offset - dt.itemsize * count
            if i == len(elements) - 1 and extra >= dt.itemsize:
                raise FormatError(f"PLY header announces {count} vertices but the file holds "
                                  f"{(len(raw) - offset) // dt.itemsize}: the vertex count is wrong", path)
            arr = np.frombuffer(raw, dtype=dt, count=count, offset=offset)
            return {p[0]: arr[p[0]].astype(arr[p[0]].dtype.newbyteorder("=")) for p in props}
        offset += dt.itemsize * count
    raise FormatError("PLY vertex element could not be located", path)


Elements = list[tuple[str, int, list[tuple[str, str | None, str]]]]
"""A PLY header's elements: (name, count, properties (name, list count type or None, type))."""


def _parse_header(header: list[str], path: Path) -> tuple[str, Elements]:
    """The format and the elements of a PLY header's lines."""
    fmt = None
    elements: Elements = []
    for line in header:
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info", "ply"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            if len(parts) != 3:
                raise FormatError(f"bad PLY element line {line.strip()!r} (expected 'element NAME COUNT')", path)
            elements.append((parts[1], _element_count(parts[2], parts[1], path), []))
        elif parts[0] == "property":
            if not elements:
                raise FormatError("PLY property before any element", path)
            if parts[1] == "list":
                elements[-1][2].append((parts[4], parts[2], parts[3]))
            else:
                if parts[1] not in _PLY_TYPES:
                    raise FormatError(f"unknown PLY property type {parts[1]!r}", path)
                elements[-1][2].append((parts[2], None, parts[1]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise FormatError(f"unsupported PLY format {fmt!r}", path)
    return fmt, elements


def _read_ascii(body: bytes, elements, vertex_idx: int, path: Path) -> dict[str, np.ndarray]:
    lines = body.decode("ascii", errors="replace").splitlines()
    skip = sum(e[1] for e in elements[:vertex_idx])
    name, count, props = elements[vertex_idx]
    if any(p[1] is not None for p in props):
        raise FormatError("list properties in the vertex element are not supported", path)
    rows = lines[skip:skip + count]
    if vertex_idx == len(elements) - 1 and any(r.strip() for r in lines[skip + count:]):
        found = sum(1 for r in lines[skip:] if r.strip())
        raise FormatError(f"PLY header announces {count} vertices but the file holds {found}: the vertex count "
                          "is wrong", path)
    if len(rows) < count:
        raise FormatError(f"PLY file is truncated: {count} vertices announced, {len(rows)} found", path)
    try:
        table = np.array([r.split()[: len(props)] for r in rows], dtype=np.float64).reshape(count, len(props))
    except ValueError as e:
        raise FormatError(f"bad number in ASCII PLY vertex data ({e})", path) from e
    return {p[0]: table[:, j].astype(_PLY_TYPES[p[2]]) for j, p in enumerate(props)}


def read_ply_faces(path: str | Path) -> np.ndarray:
    """Triangles [M,3] of a binary little-endian PLY mesh whose ``face`` element follows the vertices
    (as :func:`write_ply` writes it, with ``uchar`` counts and ``int`` indices)."""
    path = Path(path)
    raw = path.read_bytes()
    body = raw.index(b"\n", raw.find(b"end_header")) + 1
    header = raw[:body].decode("ascii", errors="replace")
    m = re.search(r"element face (\d+)\s+property list uchar u?int\S* vertex_ind\w+", header)
    if "binary_little_endian" not in header or m is None:
        raise FormatError("not a binary little-endian PLY mesh with triangle lists after the vertices", path)
    vertex = read_ply(path)
    n = len(next(iter(vertex.values())))
    vsize = sum(arr.dtype.itemsize for arr in vertex.values())
    count = int(m.group(1))
    tris = np.frombuffer(raw, dtype=[("n", "u1"), ("v", "<i4", (3,))], count=count, offset=body + n * vsize)
    if count and (tris["n"] != 3).any():
        raise FormatError("the mesh has faces that are not triangles", path)
    return tris["v"].astype(np.int64)


def ply_points(vertex: dict[str, np.ndarray], path: str | Path | None = None) -> np.ndarray:
    """[N,3] float64 coordinates from :func:`read_ply`'s dict; a clear error if x/y/z are missing."""
    missing = [k for k in "xyz" if k not in vertex]
    if missing:
        raise FormatError(f"PLY vertices lack the coordinate properties {missing}", path)
    return np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)


def ply_colors(vertex: dict[str, np.ndarray]) -> np.ndarray | None:
    """[N,3] uint8 colours if the PLY has red/green/blue, else None."""
    if not all(k in vertex for k in ("red", "green", "blue")):
        return None
    return np.stack([vertex["red"], vertex["green"], vertex["blue"]], axis=1).astype(np.uint8)
