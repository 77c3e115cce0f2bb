import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import FormatError
from mvsformerpp.io.images import find_image, image_size, list_images, read_image

from .fakes import DTU_PAIR, TEMPLE


def test_real_images():
    assert image_size(DTU_PAIR / "rect_001_0_r5000.png") == (640, 512)
    img = read_image(TEMPLE / "templeSR0001.png")
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    assert 0 < img.mean() < 255


@pytest.mark.parametrize("mode", ["L", "RGBA", "P", "LA", "I;16", "RGB"])
def test_modes_convert_to_rgb(tmp_path, mode):
    rng = np.random.default_rng(0)
    gray = rng.integers(0, 256, size=(6, 9), dtype=np.uint8)
    if mode == "I;16":
        im = Image.fromarray(gray.astype(np.uint16) * 257)  # 16-bit spanning the full range
    else:
        im = Image.fromarray(gray).convert(mode)
    im.save(tmp_path / "x.png")
    out = read_image(tmp_path / "x.png")
    assert out.shape == (6, 9, 3) and out.dtype == np.uint8
    if mode != "P":  # palette quantisation may alter values
        np.testing.assert_array_equal(out[:, :, 0], gray)
        np.testing.assert_array_equal(out[:, :, 2], gray)
    assert image_size(tmp_path / "x.png") == (9, 6)


def test_bad_images(tmp_path):
    (tmp_path / "a.jpg").write_bytes(b"not an image at all")
    with pytest.raises(FormatError, match="not a readable image"):
        image_size(tmp_path / "a.jpg")
    with pytest.raises(FormatError, match="not found"):
        read_image(tmp_path / "missing.png")
    data = (DTU_PAIR / "rect_001_0_r5000.png").read_bytes()
    (tmp_path / "t.png").write_bytes(data[: len(data) // 3])
    assert image_size(tmp_path / "t.png") == (640, 512)  # the header survives
    with pytest.raises(FormatError, match="truncated or corrupt"):
        read_image(tmp_path / "t.png")


def test_find_and_list(tmp_path):
    Image.new("RGB", (2, 2)).save(tmp_path / "00000001.JPG", format="JPEG")
    Image.new("RGB", (2, 2)).save(tmp_path / "b.png")
    (tmp_path / "notes.txt").write_text("x")
    assert find_image(tmp_path, "00000001") == tmp_path / "00000001.JPG"
    assert find_image(tmp_path, "zz") is None
    assert [p.name for p in list_images(tmp_path)] == ["00000001.JPG", "b.png"]


@pytest.mark.parametrize("scale", [1.0, 255.0, 4095.0])
def test_float_tiffs_keep_their_intensities(tmp_path, scale):
    """A 32-bit float TIFF in [0, 1] (or in 8-bit values, or another range) is a photo, not a black image."""
    rng = np.random.default_rng(1)
    gray = rng.integers(0, 256, size=(7, 5)).astype(np.float32) / 255.0
    gray[0, :2] = 0.0, 1.0  # the full range: a range other than [0, 1] or [0, 255] is stretched to it
    Image.fromarray(gray * scale if scale != 4095.0 else gray * scale + 100.0, mode="F").save(tmp_path / "f.tif")
    out = read_image(tmp_path / "f.tif")
    assert out.shape == (7, 5, 3) and out.dtype == np.uint8
    np.testing.assert_allclose(out[..., 0], np.round(gray * 255), atol=1)


def test_an_all_nan_float_image_is_refused(tmp_path):
    Image.fromarray(np.full((4, 4), np.nan, np.float32), mode="F").save(tmp_path / "nan.tif")
    with pytest.raises(FormatError, match="no finite value"):
        read_image(tmp_path / "nan.tif")
