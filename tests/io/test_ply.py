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


def test_streamed_pieces_read_back_as_one_cloud(tmp_path):
    from mvsformerpp.io.ply import PlyStreamWriter, ply_vertex_count

    rng = np.random.default_rng(1)
    pieces = [(rng.normal(size=(n, 3)).astype(np.float32), rng.integers(0, 256, (n, 3)).astype(np.uint8))
              for n in (5, 0, 17)]
    path = tmp_path / "s.ply"
    with PlyStreamWriter(path) as w:
        for xyz, rgb in pieces:
            w.write(xyz, rgb)
    v = read_ply(path)
    np.testing.assert_array_equal(ply_points(v), np.concatenate([p[0] for p in pieces]).astype(np.float64))
    np.testing.assert_array_equal(ply_colors(v), np.concatenate([p[1] for p in pieces]))
    assert ply_vertex_count(path) == 22 and w.count == 22
    # Same body as the one-shot writer.
    write_ply(tmp_path / "o.ply", *(np.concatenate(a) for a in zip(*pieces)))
    assert (tmp_path / "o.ply").read_bytes().split(b"end_header\n")[1] == path.read_bytes().split(b"end_header\n")[1]
    with PlyStreamWriter(tmp_path / "e.ply"):
        pass
    assert len(ply_points(read_ply(tmp_path / "e.ply"))) == 0


def test_a_failed_stream_leaves_no_file(tmp_path):
    from mvsformerpp.io.ply import PlyStreamWriter

    path = tmp_path / "f.ply"
    with pytest.raises(ValueError, match="fields"), PlyStreamWriter(path) as w:
        w.write(np.zeros((2, 3)), np.zeros((2, 3), np.uint8))
        w.write(np.zeros((2, 3)))  # a piece without colours
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("count", ["-1", "7", "x1"])
def test_a_wrong_vertex_count_is_refused(tmp_path, count):
    """A header whose vertex count is negative, not a number or smaller than the data is not read anyway."""
    xyz = np.arange(30, dtype=np.float32).reshape(10, 3)
    good = tmp_path / "good.ply"
    write_ply(good, xyz)
    raw = good.read_bytes()
    head = raw[:raw.index(b"end_header")]
    line = next(x for x in head.split(b"\n") if x.startswith(b"element vertex"))
    (tmp_path / "bad.ply").write_bytes(raw.replace(line, b"element vertex " + count.encode()))
    with pytest.raises(FormatError, match="count" if count != "7" else "announces 7 vertices but the file holds 10"):
        read_ply(tmp_path / "bad.ply")
    ascii_rows = "\n".join(" ".join(f"{v:g}" for v in row) for row in xyz)
    (tmp_path / "a.ply").write_text(f"ply\nformat ascii 1.0\nelement vertex {count}\nproperty float x\n"
                                    f"property float y\nproperty float z\nend_header\n{ascii_rows}\n")
    with pytest.raises(FormatError, match="count" if count != "7" else "announces 7 vertices but the file holds 10"):
        read_ply(tmp_path / "a.ply")
