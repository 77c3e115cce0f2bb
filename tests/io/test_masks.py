"""Object-mask folders: the recognised layouts and the errors for bad ones."""

import numpy as np
import pytest
from PIL import Image

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.masks import load_masks


def _mask(path, h=6, w=8, value=255, left=3):
    a = np.zeros((h, w), np.uint8)
    a[:, :left] = value
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(a).save(path)


def test_layouts(tmp_path):
    # named like the photos
    for n in ("IMG_1", "IMG_2"):
        _mask(tmp_path / "a" / f"{n}.png")
    masks = load_masks(tmp_path / "a", ["IMG_1.jpg", "IMG_2.jpg"], [(6, 8), (6, 8)])
    assert all(m.dtype == bool and m[:, :3].all() and not m[:, 3:].any() for m in masks)
    # DTU: scanN/mask/000.png beside scanN/image/, by view number
    for i in range(2):
        _mask(tmp_path / "scan1" / "mask" / f"{i:03d}.png", left=1 + i)
        _mask(tmp_path / "scan1" / "image" / f"{i:06d}.png")
    masks = load_masks(tmp_path / "scan1", ["00000000", "00000001"], [(6, 8), (6, 8)])
    assert [int(m[0].sum()) for m in masks] == [1, 2]
    # BlendedMVS: the photo with a black background, beside the photo itself
    rgb = np.full((6, 8, 3), 90, np.uint8)
    rgb[:, 5:] = 0
    (tmp_path / "bmvs" / "blended_images").mkdir(parents=True)
    (tmp_path / "bmvs" / "cams").mkdir()
    Image.fromarray(rgb).save(tmp_path / "bmvs" / "blended_images" / "00000000_masked.jpg", quality=95)
    Image.fromarray(np.full((6, 8, 3), 90, np.uint8)).save(tmp_path / "bmvs" / "blended_images" / "00000000.jpg")
    (m,) = load_masks(tmp_path / "bmvs", ["00000000"], [(6, 8)])
    assert m[:, :5].all() and not m[:, 5:].any()
    # same aspect ratio, other size: resized
    (m,) = load_masks(tmp_path / "a", ["IMG_1.jpg"], [(12, 16)])
    assert m.shape == (12, 16) and m[:, :6].all() and not m[:, 6:].any()


def test_missing_and_wrong_size(tmp_path):
    _mask(tmp_path / "m" / "IMG_1.png")
    with pytest.raises(InputError, match=r"no mask for 2 of 3 views \(IMG_2.jpg, IMG_3.jpg\)"):
        load_masks(tmp_path / "m", ["IMG_1.jpg", "IMG_2.jpg", "IMG_3.jpg"], [(6, 8)] * 3)
    with pytest.raises(FormatError, match="mask is 8x6 but its image is 6x6"):
        load_masks(tmp_path / "m", ["IMG_1.jpg"], [(6, 6)])
    with pytest.raises(InputError, match="mask folder not found"):
        load_masks(tmp_path / "nope", ["IMG_1.jpg"], [(6, 8)])


@pytest.mark.parametrize("mode", ["RGBA", "LA"])
def test_masks_with_alpha_use_the_alpha_channel(tmp_path, mode):
    """A cut-out (white object on a transparent background, or any colour) is read by its alpha."""
    alpha = np.zeros((6, 8), np.uint8)
    alpha[:, :3] = 255
    rgb = np.full((6, 8, 3), 255, np.uint8)  # white everywhere: the grey value says nothing
    im = Image.fromarray(np.dstack([rgb, alpha]), "RGBA")
    (tmp_path / "m").mkdir()
    (im if mode == "RGBA" else im.convert("LA")).save(tmp_path / "m" / "IMG_1.png")
    (m,) = load_masks(tmp_path / "m", ["IMG_1.jpg"], [(6, 8)])
    assert m[:, :3].all() and not m[:, 3:].any()
    # an opaque alpha channel says nothing: the grey value decides as for any mask
    grey = np.dstack([np.repeat(alpha[..., None], 3, -1), np.full((6, 8), 255, np.uint8)])
    Image.fromarray(grey, "RGBA").save(tmp_path / "m" / "IMG_1.png")
    (m,) = load_masks(tmp_path / "m", ["IMG_1.jpg"], [(6, 8)])
    assert m[:, :3].all() and not m[:, 3:].any()


def test_masks_that_mark_nothing_are_refused(tmp_path):
    for n in ("IMG_1", "IMG_2"):
        _mask(tmp_path / "m" / f"{n}.png", left=0)
    with pytest.raises(InputError, match="the masks mark no pixel of any view as object"):
        load_masks(tmp_path / "m", ["IMG_1.jpg", "IMG_2.jpg"], [(6, 8), (6, 8)])
    _mask(tmp_path / "m" / "IMG_2.png", left=2)  # one view without the object is fine
    masks = load_masks(tmp_path / "m", ["IMG_1.jpg", "IMG_2.jpg"], [(6, 8), (6, 8)])
    assert not masks[0].any() and masks[1].any()
