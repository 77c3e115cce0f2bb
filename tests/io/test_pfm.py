import numpy as np
import pytest

from mvsformerpp.errors import FormatError
from mvsformerpp.io.pfm import read_pfm, write_pfm


@pytest.mark.parametrize("shape", [(5, 7), (4, 3, 3)])
def test_round_trip_is_exact_and_top_down(tmp_path, shape):
    arr = np.random.default_rng(1).normal(size=shape).astype(np.float32)
    write_pfm(tmp_path / "a.pfm", arr)
    np.testing.assert_array_equal(read_pfm(tmp_path / "a.pfm"), arr)
    # The file stores rows bottom-up: the first data row is the array's last row.
    raw = (tmp_path / "a.pfm").read_bytes()
    first = np.frombuffer(raw.split(b"-1.0\n", 1)[1], "<f4", count=int(np.prod(shape[1:])))
    np.testing.assert_array_equal(first, arr[-1].reshape(-1))


def test_big_endian_file(tmp_path):
    arr = np.arange(6, dtype=np.float32).reshape(2, 3)
    (tmp_path / "b.pfm").write_bytes(b"Pf\n3 2\n1.0\n" + np.flipud(arr).astype(">f4").tobytes())
    np.testing.assert_array_equal(read_pfm(tmp_path / "b.pfm"), arr)


def test_real_dtu_depth(tmp_path):
    from pathlib import Path

    depth = read_pfm(Path(__file__).parents[1] / "data/dtu_pair/depth_map_0000.pfm")
    assert depth.shape == (128, 160)
    valid = depth[depth > 0]
    assert 0.7 < valid.size / depth.size < 0.9
    assert 480 < valid.min() and valid.max() < 830


def test_truncated_and_garbage(tmp_path):
    (tmp_path / "t.pfm").write_bytes(b"Pf\n3 2\n-1.0\n" + b"\0" * 8)
    with pytest.raises(FormatError, match="truncated"):
        read_pfm(tmp_path / "t.pfm")
    (tmp_path / "g.pfm").write_bytes(b"P6\n3 2\n255\n")
    with pytest.raises(FormatError, match="not a PFM"):
        read_pfm(tmp_path / "g.pfm")
