import logging
import string

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.mvsnet import (
    MVSNetCam,
    format_cam,
    load_mvsnet_scene,
    read_cam,
    read_pair,
    write_cam,
    write_mvsnet_scene,
    write_pair,
)

from .fakes import DTU_PAIR, make_dtu_mvsnet


def rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def cam_text(depth_line: str, K=((100, 0, 32), (0, 100, 24), (0, 0, 1))) -> str:
    E = np.eye(4)
    rows = "\n".join(" ".join(str(v) for v in r) for r in E)
    krows = "\n".join(" ".join(str(v) for v in r) for r in K)
    return f"extrinsic\n{rows}\n\nintrinsic\n{krows}\n\n{depth_line}\n"


def test_real_dtu_cam():
    cam = read_cam(DTU_PAIR / "00000000_cam.txt")
    assert cam.extrinsic[0, 3] == pytest.approx(-191.02)
    assert cam.K[0, 0] == pytest.approx(361.54125)
    # "425.0 2.5" is the interval form: 192 planes from 425 mm in 2.5 mm steps.
    assert cam.depth_min == 425.0 and cam.depth_interval == 2.5
    assert cam.depth_max == pytest.approx(425.0 + 2.5 * 191)
    assert cam.num_depth is None
    # The GT depth of this view (492..814 mm) lies inside that range.
    assert cam.depth_min < 492 and cam.depth_max > 814


@pytest.mark.parametrize(
    "line, fmt, expect",
    [
        ("425 2.5", "auto", (425, 425 + 2.5 * 191, 2.5, None)),  # DTU interval form
        ("0.5 12", "auto", (0.5, 12, 11.5 / 191, None)),  # newer converters: min max
        ("2 3", "auto", (2, 3, 1 / 191, None)),  # second > first: a max (as interval: 2..575)
        ("2 3", "interval", (2, 2 + 3 * 191, 3, None)),  # forced
        ("425 2.5 128 742.5", "auto", (425, 742.5, 2.5, 128)),
        ("425 2.5 128", "auto", (425, 425 + 2.5 * 127, 2.5, 128)),
        ("1 2.0", "max", (1, 2, 1 / 191, None)),
    ],
)
def test_depth_line_forms(tmp_path, line, fmt, expect):
    p = tmp_path / "00000000_cam.txt"
    p.write_text(cam_text(line))
    cam = read_cam(p, depth_format=fmt)
    got = (cam.depth_min, cam.depth_max, cam.depth_interval, cam.num_depth)
    np.testing.assert_allclose(got[:3], expect[:3], rtol=1e-12)
    assert got[3] == expect[3]


def test_depth_line_missing_or_ignored(tmp_path):
    p = tmp_path / "c.txt"
    p.write_text(cam_text(""))
    assert read_cam(p).depth_min is None
    p.write_text(cam_text("425 2.5"))
    assert read_cam(p, depth_format="none").depth_max is None


@pytest.mark.parametrize(
    "text, match",
    [
        (cam_text("nan 2.5"), "non-finite"),
        (cam_text("425 inf"), "non-finite"),
        (cam_text("425"), "only one number"),
        (cam_text("0 2.5"), "0 < min < max"),
        (cam_text("5 3"), None),
        (cam_text("425 2.5 1.5 600"), "DEPTH_NUM"),
        (cam_text("1 2 3 4 5"), "2 to 4 numbers"),
        (cam_text("1 2", K=((0, 0, 32), (0, 100, 24), (0, 0, 1))), "fx, fy > 0"),
        ("intrinsic\n1 0 0\n0 1 0\n0 0 1\n", "headers are missing"),
        ("extrinsic\n1 0 0 0\nintrinsic\n1 0 0 0 1 0 0 0 1\n", "16 numbers"),
        (cam_text("1 2").replace("1.0 0.0 0.0 0.0", "2.0 0.0 0.0 0.0", 1), "rotation"),
        (cam_text("1 2").replace("0.0 0.0 0.0 1.0", "0.0 0.0 1.0 1.0"), "0 0 0 1"),
        (cam_text("1 2").replace("100", "abc", 1), "expected numbers"),
    ],
)
def test_malformed_cams(tmp_path, text, match):
    p = tmp_path / "00000003_cam.txt"
    p.write_text(text)
    if match is None:  # valid: "5 3" is min 5 + interval 3 (3 < 5), so no error
        read_cam(p)
        return
    with pytest.raises(FormatError, match=match) as e:
        read_cam(p)
    assert "00000003_cam.txt" in str(e.value)


def test_missing_cam(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_cam(tmp_path / "nope_cam.txt")
    (tmp_path / "bin_cam.txt").write_bytes(b"\xff\xfe\x00extrinsic")
    with pytest.raises(FormatError, match="not text"):
        read_cam(tmp_path / "bin_cam.txt")


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=st.integers(0, 2**31),
    t=st.lists(finite, min_size=3, max_size=3),
    f=st.floats(1e-3, 1e5),
    c=st.lists(st.floats(-1e4, 1e4), min_size=2, max_size=2),
    dmin=st.floats(1e-4, 1e5),
    ratio=st.floats(1.0001, 1e3),
    n=st.integers(2, 1024),
)
def test_cam_round_trip(tmp_path, seed, t, f, c, dmin, ratio, n):
    E = np.eye(4)
    E[:3, :3] = rotation(seed)
    E[:3, 3] = t
    K = np.array([[f, 0, c[0]], [0, f * 1.01, c[1]], [0, 0, 1]])
    cam = MVSNetCam(extrinsic=E, K=K, depth_min=dmin, depth_max=dmin * ratio, num_depth=n)
    write_cam(tmp_path / "r_cam.txt", cam)
    back = read_cam(tmp_path / "r_cam.txt")
    np.testing.assert_array_equal(back.extrinsic, E)
    np.testing.assert_array_equal(back.K, K)
    assert back.depth_min == dmin and back.depth_max == dmin * ratio and back.num_depth == n
    assert back.depth_interval == pytest.approx((dmin * ratio - dmin) / (n - 1), rel=1e-12)


cam_alphabet = string.digits + "-+.eE \n\tnaifxtrinsc"


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(
    st.text(alphabet=cam_alphabet, max_size=300),
    st.binary(max_size=200),
    st.builds(lambda s: cam_text("1 2").replace("1.0", s, 1), st.text(alphabet=cam_alphabet, max_size=12)),
    st.builds(lambda s: cam_text(s), st.text(alphabet=cam_alphabet, max_size=30)),
))
def test_cam_garbage_raises_only_format_error(tmp_path, data):
    p = tmp_path / "g_cam.txt"
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    try:
        cam = read_cam(p)
    except FormatError:
        return
    assert np.all(np.isfinite(cam.extrinsic)) and np.all(np.isfinite(cam.K))


def test_pair_round_trip_and_real_layout(tmp_path):
    pairs = {0: [(1, 2345.5), (2, 12.0)], 1: [(0, 2345.5)], 2: []}
    write_pair(tmp_path / "pair.txt", pairs)
    assert (tmp_path / "pair.txt").read_text().splitlines()[:3] == ["3", "0", "2 1 2345.5 2 12.0"]
    assert read_pair(tmp_path / "pair.txt") == pairs
    # The DTU / MVSNet style with integer-looking scores and trailing spaces reads too.
    (tmp_path / "p2.txt").write_text("2\n0\n1 1 2412.25 \n1\n1 0 2412.25 \n")
    assert read_pair(tmp_path / "p2.txt") == {0: [(1, 2412.25)], 1: [(0, 2412.25)]}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.dictionaries(
    st.integers(0, 10**6),
    st.lists(st.tuples(st.integers(0, 10**6), st.floats(allow_nan=False, allow_infinity=False)), max_size=12,
             unique_by=lambda src: src[0]),  # each source view once per reference
    max_size=20,
))
def test_pair_round_trip_property(tmp_path, pairs):
    write_pair(tmp_path / "pair.txt", pairs)
    assert read_pair(tmp_path / "pair.txt") == pairs


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.one_of(st.text(alphabet=string.digits + "-+.eE \nnaif", max_size=120), st.binary(max_size=80)))
def test_pair_garbage_raises_only_format_error(tmp_path, data):
    p = tmp_path / "pair.txt"
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    try:
        pairs = read_pair(p)
    except FormatError:
        return
    assert all(isinstance(k, int) for k in pairs)


@pytest.mark.parametrize(
    "text, match",
    [("2\n0\n1 1 10\n", "ends early"), ("1\n0\n1 x 3\n", "integer"), ("1\n0\n1 1 nan\n", "not finite"),
     ("1\n0\n0\n7", "unexpected text"), ("2\n0\n0\n0\n0\n", "listed twice"), ("-1\n", "non-negative")],
)
def test_malformed_pairs(tmp_path, text, match):
    (tmp_path / "pair.txt").write_text(text)
    with pytest.raises(FormatError, match=match):
        read_pair(tmp_path / "pair.txt")


def test_load_real_dtu_scene_resolves_integer_scale(tmp_path, caplog):
    root = make_dtu_mvsnet(tmp_path / "scene")
    with caplog.at_level(logging.WARNING):
        scene = load_mvsnet_scene(root)
    assert "K scaled by 4" in caplog.text
    scene.validate()
    assert [v.name for v in scene.views] == ["00000000", "00000001"]
    v = scene.views[0]
    assert (v.width, v.height) == (640, 512)
    cam = read_cam(DTU_PAIR / "00000000_cam.txt")
    np.testing.assert_allclose(v.K[:2], cam.K[:2] * 4)
    np.testing.assert_array_equal(v.R, cam.R)
    assert v.neighbors == [1] and scene.views[1].neighbors == [0]
    assert v.depth_min == 425.0 and v.depth_max == pytest.approx(425 + 2.5 * 191)
    scaled = load_mvsnet_scene(root, interval_scale=1.06)
    assert scaled.views[0].depth_max == pytest.approx(425 + 2.5 * 191 * 1.06)


def test_scene_without_pair_gets_geometric_neighbours(tmp_path):
    root = make_dtu_mvsnet(tmp_path / "scene", pair=False)
    scene = load_mvsnet_scene(root)
    assert scene.views[0].neighbors == [1] and scene.views[1].neighbors == [0]
    # A pair.txt kept in cams/ is found too.
    write_pair(root / "cams" / "pair.txt", {0: [], 1: [(0, 1.0)]})
    scene = load_mvsnet_scene(root)
    assert scene.views[0].neighbors == [] and scene.views[1].neighbors == [0]


def test_write_then_load_scene(tmp_path):
    scene = load_mvsnet_scene(make_dtu_mvsnet(tmp_path / "a"))
    write_mvsnet_scene(scene, tmp_path / "b")
    back = load_mvsnet_scene(tmp_path / "b")
    for v, w in zip(scene.views, back.views):
        np.testing.assert_array_equal(v.K, w.K)  # now at full resolution: no rescaling on reload
        np.testing.assert_array_equal(v.extrinsic, w.extrinsic)
        assert (v.depth_min, v.depth_max) == (w.depth_min, w.depth_max)
        assert v.neighbors == w.neighbors
        assert w.image_path.read_bytes() == v.image_path.read_bytes()
    assert len(format_cam(read_cam(tmp_path / "b/cams/00000000_cam.txt")).splitlines()[-1].split()) == 4


def test_scene_errors(tmp_path):
    root = make_dtu_mvsnet(tmp_path / "s")
    write_pair(root / "pair.txt", {0: [(1, 1.0), (5, 1.0)], 1: [(0, 1.0)]})
    with pytest.raises(InputError, match=r"references view\(s\) \[5\]") as e:
        load_mvsnet_scene(root)
    assert "pair.txt" in str(e.value)
    write_pair(root / "pair.txt", {0: [(1, 1.0)], 1: [(0, 1.0)]})
    # A photo whose size fits no integer rescaling of the camera.
    Image.new("RGB", (300, 700)).save(root / "images" / "00000001.png")
    with pytest.raises(InputError, match="does not fit the 300x700 image"):
        load_mvsnet_scene(root)
    (root / "images" / "00000001.png").unlink()
    with pytest.raises(InputError, match="no image for camera 00000001_cam.txt"):
        load_mvsnet_scene(root)
    for p in (root / "cams").iterdir():
        p.unlink()
    with pytest.raises(InputError, match="empty"):
        load_mvsnet_scene(root)
    with pytest.raises(InputError, match="not a folder"):
        load_mvsnet_scene(tmp_path / "missing")


def test_two_cam_files_for_one_view_are_refused(tmp_path):
    root = make_dtu_mvsnet(tmp_path / "s")
    (root / "cams" / "1_cam.txt").write_text((root / "cams" / "00000001_cam.txt").read_text())
    with pytest.raises(InputError, match="two cam files for view 1: 00000001_cam.txt and 1_cam.txt"):
        load_mvsnet_scene(root)


def test_an_absurd_focal_length_is_refused(tmp_path):
    root = make_dtu_mvsnet(tmp_path / "s")
    cam = read_cam(root / "cams" / "00000001_cam.txt")
    cam.K[0, 0] = cam.K[1, 1] = 1e30
    write_cam(root / "cams" / "00000001_cam.txt", cam)
    with pytest.raises(InputError, match="field of view of .* degrees .* the intrinsics are wrong"):
        load_mvsnet_scene(root).validate()
    cam.K[0, 0] = cam.K[1, 1] = 20000.0  # a long telephoto (2 degrees at 640 px): fine
    write_cam(root / "cams" / "00000001_cam.txt", cam)
    load_mvsnet_scene(root).validate()


def test_text_files_saved_with_a_byte_order_mark_read_as_without(tmp_path):
    """Editors on Windows save UTF-8 with a BOM; cam files, pair files, Middlebury par files and COLMAP text
    read the same with one."""
    from mvsformerpp.io.colmap_model import read_images_text
    from mvsformerpp.io.middlebury import read_par

    bom = b"\xef\xbb\xbf"
    src = DTU_PAIR / "00000000_cam.txt"
    (tmp_path / "0_cam.txt").write_bytes(bom + src.read_bytes())
    np.testing.assert_array_equal(read_cam(tmp_path / "0_cam.txt").K, read_cam(src).K)
    (tmp_path / "pair.txt").write_bytes(bom + b"2\n0\n1 1 1.0\n1\n1 0 1.0\n")
    assert read_pair(tmp_path / "pair.txt")[0] == [(1, 1.0)]
    (tmp_path / "images.txt").write_bytes(bom + b"1 1 0 0 0 0 0 0 1 a.png\n\n")
    assert read_images_text(tmp_path / "images.txt")[1].name == "a.png"
    line = "a.png 500 0 320 0 500 240 0 0 1 1 0 0 0 1 0 0 0 1 0 0 1"  # K, R = I, t
    (tmp_path / "x_par.txt").write_bytes(bom + f"1\n{line}\n".encode())
    assert len(read_par(tmp_path / "x_par.txt")) == 1
