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

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NUMPY_TO_PLY = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
                 "u4": "uint", "f4": "float", "f8": "double"}


def write_ply(
    path: str | Path,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    extra: dict[str, np.ndarray] | None = None,
    faces: np.ndarray | None = None,
) -> None:
    """Write a binary little-endian PLY point cloud (or mesh, with ``faces``) atomically.

    xyz: [N,3] (stored as float32); rgb: [N,3] uint8 or floats in [0,1]; normals: [N,3];
    extra: name -> [N] scalar arrays (e.g. ``confidence``), stored with their own dtype;
    faces: [M,3] vertex indices of triangles (a ``face`` element with ``vertex_indices`` lists).
    """
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
    record = np.dtype([(name, dt) for name, dt, _ in fields])
    data = np.empty(n, dtype=record)
    for name, _, values in fields:
        data[name] = values
    header = ["ply", "format binary_little_endian 1.0", "comment written by mvsformerpp", f"element vertex {n}"]
    for name, dt, _ in fields:
        header.append(f"property {_NUMPY_TO_PLY[dt.str[1:]]} {name}")
    tris = None
    if faces is not None:
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must be [M,3], got {faces.shape}")
        tris = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        tris["n"], tris["v"] = 3, faces
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    header.append("end_header")
    with atomic_open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())
        if tris is not None:
            f.write(tris.tobytes())


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
    header = raw[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str | None, str]]]] = []
    for line in header:
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info", "ply"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
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
            arr = np.frombuffer(raw, dtype=dt, count=count, offset=offset)
            return {p[0]: arr[p[0]].astype(arr[p[0]].dtype.newbyteorder("=")) for p in props}
        offset += dt.itemsize * count
    raise FormatError("PLY vertex element could not be located", path)


def _read_ascii(body: bytes, elements, vertex_idx: int, path: Path) -> dict[str, np.ndarray]:
    lines = body.decode("ascii", errors="replace").splitlines()
    skip = sum(e[1] for e in elements[:vertex_idx])
    name, count, props = elements[vertex_idx]
    if any(p[1] is not None for p in props):
        raise FormatError("list properties in the vertex element are not supported", path)
    rows = lines[skip:skip + count]
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
