import numpy as np
import pytest

from mvsformerpp.errors import FormatError
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply, write_ply


def test_binary_round_trip_with_colours_normals_and_extra(tmp_path):
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(100, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(100, 3)).astype(np.uint8)
    nrm = rng.normal(size=(100, 3)).astype(np.float32)
    conf = rng.random(100).astype(np.float32)
    path = tmp_path / "c.ply"
    write_ply(path, xyz, rgb, normals=nrm, extra={"confidence": conf})
    v = read_ply(path)
    np.testing.assert_array_equal(ply_points(v), xyz.astype(np.float64))
    np.testing.assert_array_equal(ply_colors(v), rgb)
    np.testing.assert_array_equal(v["nx"], nrm[:, 0])
    np.testing.assert_array_equal(v["confidence"], conf)


def test_ascii_and_big_endian_with_trailing_faces(tmp_path):
    ascii_ply = tmp_path / "a.ply"
    ascii_ply.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3\n4 5 6\n3 0 1 1\n"
    )
    np.testing.assert_array_equal(ply_points(read_ply(ascii_ply)), [[1, 2, 3], [4, 5, 6]])
    big = tmp_path / "b.ply"
    pts = np.array([[1.5, -2.0, 3.25]], dtype=">f8")
    big.write_bytes(
        b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
        b"property double z\nend_header\n" + pts.tobytes()
    )
    np.testing.assert_array_equal(ply_points(read_ply(big)), [[1.5, -2.0, 3.25]])


def test_bad_files_raise_clear_errors(tmp_path):
    p = tmp_path / "x.ply"
    p.write_bytes(b"hello")
    with pytest.raises(FormatError, match="not a PLY"):
        read_ply(p)
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n")
    with pytest.raises(FormatError, match="truncated"):
        read_ply(p)
    write_ply(p, np.zeros((0, 3)))
    with pytest.raises(FormatError, match="coordinate"):
        ply_points({"x": np.zeros(1)})
