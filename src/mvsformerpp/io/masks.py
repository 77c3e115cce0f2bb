"""Object masks: which pixels of each photo belong to the object to reconstruct.

A mask folder is matched to the views by file name; these layouts are recognised:

* one mask per photo with the photo's name (any image suffix): ``IMG_0001.png`` for ``IMG_0001.jpg``;
* numbered by view index: ``NNNNNNNN.png`` (this package and MVSNet), ``NNN.png`` or ``NNNN.png``
  (DTU's object masks, ``scanN/mask/000.png``; a DTU scan folder with ``mask/`` inside is accepted);
* BlendedMVS: ``blended_images/NNNNNNNN_masked.jpg`` (the photo with the background blacked out; a
  BlendedMVS scene folder is accepted), a pixel belongs to the object where it is not black.

Binary masks count a pixel as object where its grey value is above half; a mask with an alpha channel
(RGBA, grey + alpha, a palette with transparency) counts the pixels whose alpha is above half, unless
it is opaque everywhere. A mask must have its
photo's aspect ratio; it is resized (nearest) to the size it is applied at.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mvsformerpp.errors import FormatError, InputError
from mvsformerpp.io.images import find_image, image_size, read_alpha, read_image

# Black threshold of BlendedMVS's masked photos (JPEG leaves some noise in the black background).
_MASKED_PHOTO_BLACK = 10


def mask_folder(path: str | Path) -> Path:
    """The folder that holds the masks: ``path`` itself, or its ``mask/``, ``masks/`` or ``blended_images/``."""
    path = Path(path)
    if not path.is_dir():
        raise InputError("mask folder not found", path)
    for sub in ("mask", "masks", "blended_images"):
        if (path / sub).is_dir() and not any(_is_image(p) for p in path.iterdir()):
            return path / sub
    return path


def _is_image(p: Path) -> bool:
    return p.is_file() and find_image(p.parent, p.stem) == p


def find_mask(folder: Path, index: int, name: str) -> Path | None:
    """The mask of view ``index`` whose photo is called ``name`` (stem or file name), or None.

    Tried in order: BlendedMVS's ``<stem>_masked``, the photo's stem, then its number (when the stem is
    one) and the view index written with 8, 3 and 4 digits.
    """
    stem = Path(name).stem
    numbers = ([int(stem)] if stem.isdigit() else []) + [index]
    cands = [f"{stem}_masked", stem] + [f"{n:0{k}d}{suffix}" for n in numbers for suffix in ("_masked", "")
                                        for k in (8, 3, 4)]
    for cand in dict.fromkeys(cands):
        found = find_image(folder, cand)
        if found is not None:
            return found
    return None


def read_mask(path: str | Path) -> np.ndarray:
    """A mask file as bool ``[H, W]`` (True = object)."""
    path = Path(path)
    alpha = read_alpha(path)
    if alpha is not None:
        return alpha > 127.5
    rgb = read_image(path)
    if path.stem.endswith("_masked"):
        return rgb.max(axis=-1) > _MASKED_PHOTO_BLACK
    return rgb.mean(axis=-1) > 127.5


def _check_aspect(h: int, w: int, height: int, width: int, where: Path) -> None:
    if abs(w / h - width / height) > 0.01 * width / height:
        raise FormatError(f"mask is {w}x{h} but its image is {width}x{height} (another aspect ratio): "
                          "give the masks of these photos", where)


def fit_mask(mask: np.ndarray, height: int, width: int, where: Path) -> np.ndarray:
    """Resize a mask to ``height x width`` (nearest); refuse one of another aspect ratio."""
    h, w = mask.shape
    if (h, w) == (height, width):
        return mask
    _check_aspect(h, w, height, width, where)
    from PIL import Image

    return np.asarray(Image.fromarray(mask).resize((width, height), Image.NEAREST))


def mask_paths(path: str | Path, names: list[str]) -> list[Path]:
    """The mask file of every view (``names`` of the photos); :class:`InputError` naming views without one."""
    folder = mask_folder(path)
    paths = [find_mask(folder, i, n) for i, n in enumerate(names)]
    missing = [n for n, p in zip(names, paths) if p is None]
    if missing:
        raise InputError(
            f"no mask for {len(missing)} of {len(names)} views ({', '.join(missing[:5])}"
            f"{' ...' if len(missing) > 5 else ''}); name masks like the photos (IMG_1.png for IMG_1.jpg) "
            "or by view index (00000000.png or 000.png)", folder)
    return paths


def check_mask_size(path: Path, height: int, width: int) -> None:
    """Refuse a mask whose aspect ratio is not its image's (header read only)."""

    w, h = image_size(path)
    _check_aspect(h, w, height, width, path)


def load_masks(path: str | Path, names: list[str], sizes: list[tuple[int, int]]) -> list[np.ndarray]:
    """One bool mask per view (``names`` of the photos, ``sizes`` as (height, width) to apply them at).

    Raises :class:`InputError` naming the views without a mask, the first mask of a wrong size, or masks
    that mark no pixel of any view as object.
    """
    masks = [fit_mask(read_mask(p), h, w, p) for p, (h, w) in zip(mask_paths(path, names), sizes)]
    if masks and not any(m.any() for m in masks):
        raise InputError(EMPTY_MASKS, mask_folder(path))
    return masks


EMPTY_MASKS = ("the masks mark no pixel of any view as object (all black, or all transparent): object pixels must be "
               "white (grey above 127) or, in masks with an alpha channel, opaque")
