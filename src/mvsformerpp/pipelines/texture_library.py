"""``textures``: build a texture library (:mod:`mvsformerpp.synth.texture_library`) from a folder of photographs.

Every photo (any depth below the folder) needs a licence: a ``source.json`` in its folder or a folder above
it, ``{"licence": "CC0-1.0", "source": "...", "url": "...", "author": "...", "max_textures": N}``, names
where the photos in that tree come from (``max_textures``, optional: the most textures they give, as
:attr:`LibraryConfig.max_per_source` for that source alone). Only licences that allow training and
shipping the weights are accepted (:data:`LICENCES`). From each photo the library takes random square
crops at several scales (the photo as it is, then halved, quartered, ...: texels of real materials at the
full resolution and coarser), drops crops with almost no contrast (blank sky, black borders) and
near-duplicates (the same view twice, a repeated tile), and records per crop its photo, source, licence,
box in the photo and colour statistics.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError

LICENCES = ("CC0-1.0", "public-domain", "MIT")
"""Licences a library accepts, besides ``CC-BY-<version>`` (attribution only: no NC, SA or ND terms)."""
SOURCE_FILE = "source.json"


@dataclass(frozen=True)
class LibraryConfig:
    """How crops are cut from the photos (saved in the manifest)."""

    crop: int = 384
    """Side of a crop in pixels (the generator's textures are at most 384 px: ``synth.photos.MAX_SIDE``)."""
    crops_per_scale: int = 4
    """Random crops per photo and scale; a photo smaller than ``crop`` (at least ``min_side``) is one texture."""
    max_scales: int = 4
    """Scales per photo: 1, 1/2, 1/4, ... while the scaled photo still holds a crop."""
    min_side: int = 64
    """Photos whose shorter side is below this are skipped (too small to make a texture)."""
    min_contrast: float = 4.0
    """Least standard deviation of a crop's grey level (0-255): below it the crop is too flat to keep."""
    duplicate_bits: int = 6
    """Two crops whose 64-bit grey-level hashes differ in at most this many bits and whose mean colours
    differ by less than ``duplicate_colour`` are duplicates (the later one is dropped)."""
    duplicate_colour: float = 8.0
    """Mean-colour distance (0-255, Euclidean over RGB) under which hash-equal crops count as duplicates."""
    max_per_source: int | None = None
    """Most textures one ``source.json`` contributes, spread over all of its photos (each gives at most its
    share, a random choice among its crops): a capture of one object in dozens of views would otherwise fill
    the library. None: no cap."""
    seed: int = 0
    """Seed of the photos' order and the crop positions."""


def licence_allowed(licence: str) -> bool:
    """True for the licences of :data:`LICENCES` and plain attribution licences (``CC-BY-4.0``)."""
    return licence in LICENCES or re.fullmatch(r"CC-BY-\d\.\d", licence) is not None


def _source_of(photo: Path, root: Path, cache: dict) -> dict:
    """The ``source.json`` nearest above ``photo`` (inside ``root``), checked; :class:`InputError` without one."""
    folder = photo.parent
    while True:
        if folder not in cache:
            path = folder / SOURCE_FILE
            if path.is_file():
                try:
                    info = json.loads(path.read_text())
                except (OSError, ValueError) as e:
                    raise InputError(f"cannot read the photos' source file ({e})", path) from e
                if not isinstance(info, dict) or not isinstance(info.get("licence"), str) \
                        or not isinstance(info.get("source"), str):
                    raise InputError('a source file needs {"licence": "...", "source": "..."} (url and author '
                                     "optional)", path)
                cap = info.get("max_textures")
                if cap is not None and (isinstance(cap, bool) or not isinstance(cap, int) or cap < 1):
                    raise InputError(f"max_textures must be a whole number >= 1, got {cap!r}", path)
                if not licence_allowed(info["licence"]):
                    raise InputError(f"licence {info['licence']!r} does not allow training and shipping weights; "
                                     f"accepted: {', '.join(LICENCES)} or CC-BY-<version>", path)
                cache[folder] = info
            else:
                cache[folder] = None
        if cache[folder] is not None:
            return cache[folder]
        if folder == root:
            raise InputError(f"no {SOURCE_FILE} in its folder or above: say where the photos come from and their "
                             'licence ({"licence": "CC0-1.0", "source": "..."})', photo)
        folder = folder.parent


def list_photos(folder: str | Path) -> list[Path]:
    """Image files under ``folder`` (any depth), sorted; :class:`InputError` if there is none."""
    from mvsformerpp.io.images import IMAGE_SUFFIXES

    root = Path(folder)
    if not root.is_dir():
        raise InputError("photo folder not found", root)
    photos = sorted(p for p in root.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    if not photos:
        raise InputError(f"no photos ({', '.join(IMAGE_SUFFIXES)}) in this folder or below; give a folder of "
                         "photographs", root)
    return photos


def average_hash(grey: np.ndarray) -> np.ndarray:
    """64-bit hash of a grey image [H, W] as bool [64]: its 8x8 box-averaged thumbnail above its mean."""
    h, w = grey.shape
    ys, xs = np.linspace(0, h, 9).astype(int), np.linspace(0, w, 9).astype(int)
    cells = np.array([[grey[ys[i]:ys[i + 1], xs[j]:xs[j + 1]].mean() for j in range(8)] for i in range(8)])
    return (cells > cells.mean()).ravel()


def _crops(image: np.ndarray, config: LibraryConfig, rng: np.random.Generator):
    """(crop [S,S,3], scale, box (x0, y0, x1, y1) in the photo's pixels) for every scale that holds a crop."""
    from PIL import Image

    h, w = image.shape[:2]
    if min(h, w) < config.crop:  # a small photo is one texture as it is
        yield image, 1.0, (0, 0, w, h)
        return
    pil = Image.fromarray(image)
    for k in range(config.max_scales):
        s = 0.5**k
        sw, sh = round(w * s), round(h * s)
        if min(sw, sh) < config.crop:
            break
        scaled = np.asarray(pil.resize((sw, sh), Image.BOX)) if k else image
        for _ in range(config.crops_per_scale):
            x, y = int(rng.integers(0, sw - config.crop + 1)), int(rng.integers(0, sh - config.crop + 1))
            box = tuple(round(v / s) for v in (x, y, x + config.crop, y + config.crop))
            yield scaled[y:y + config.crop, x:x + config.crop], s, box


def build_texture_library(config: LibraryConfig, photos_dir: str | Path, out: str | Path,
                          progress: bool = True) -> Path:
    """Write the library of ``photos_dir``'s photos into ``out`` (new or an earlier library); returns ``out``.

    Every photo is checked before anything is written: a photo without an accepted licence, an unreadable one
    or a folder with no photo large enough to crop stops the build with the file and the fix.
    """
    from tqdm import tqdm

    from mvsformerpp.io.images import image_size, read_image
    from mvsformerpp.synth.texture_library import MANIFEST, MIN_TEXTURES
    from mvsformerpp.synth.writer import save_png
    from mvsformerpp.utils.atomic import atomic_write_text
    from mvsformerpp.utils.output_guard import claim_output_folder

    root = Path(photos_dir)
    photos = list_photos(root)
    sources: dict = {}
    usable = []
    for p in photos:
        info = _source_of(p, root, sources)
        w, h = image_size(p)  # unreadable files stop here, before any output
        if min(w, h) >= config.min_side:
            usable.append((p, info))
    if not usable:
        raise InputError(f"none of the {len(photos)} photos is at least {config.min_side} pixels on its shorter "
                         "side: too small to crop textures from", root)
    rng = np.random.default_rng(config.seed)
    usable = [usable[i] for i in rng.permutation(len(usable))]
    entries, hashes, means, per_source = [], [], [], {}
    dropped = {"flat": 0, "duplicate": 0, "too_small": len(photos) - len(usable), "over_cap": 0}
    with claim_output_folder(out, inputs=[root], kind="textures", reuse=True) as out:
        (out / "crops").mkdir(exist_ok=True)
        photos_of = {}
        for _, info in usable:
            photos_of[info["source"]] = photos_of.get(info["source"], 0) + 1
        for p, info in tqdm(usable, desc="textures", unit="photo", disable=not progress):
            crops = list(_crops(read_image(p), config, rng))
            cap = info.get("max_textures", config.max_per_source)
            share = len(crops) if cap is None else -(-cap // photos_of[info["source"]])
            taken = 0
            for k in rng.permutation(len(crops)):
                crop, scale, box = crops[k]
                if taken >= share or (cap is not None and per_source.get(info["source"], 0) >= cap):
                    dropped["over_cap"] += 1
                    continue
                grey = crop.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
                if grey.std() < config.min_contrast:
                    dropped["flat"] += 1
                    continue
                mean = crop.reshape(-1, 3).mean(0)
                code = average_hash(grey)
                if entries and np.any(((np.asarray(hashes) != code).sum(1) <= config.duplicate_bits)
                                      & (np.linalg.norm(np.asarray(means) - mean, axis=1) < config.duplicate_colour)):
                    dropped["duplicate"] += 1
                    continue
                name = f"crops/{len(entries):06d}.png"
                save_png(out / name, crop)
                hashes.append(code)
                means.append(mean)
                per_source[info["source"]] = per_source.get(info["source"], 0) + 1
                taken += 1
                entries.append({"file": name, "photo": p.relative_to(root).as_posix(), "source": info["source"],
                                "url": info.get("url", ""), "licence": info["licence"],
                                "author": info.get("author", ""), "scale": scale, "box": list(box),
                                "size": [int(crop.shape[1]), int(crop.shape[0])],
                                "mean": [round(float(v), 2) for v in mean],
                                "std": [round(float(v), 2) for v in crop.reshape(-1, 3).std(0)]})
        if len(entries) < MIN_TEXTURES:
            raise InputError(f"only {len(entries)} textures survived (fewer than {MIN_TEXTURES}; dropped: {dropped}); "
                             "give more photos, or lower --min-contrast", root)
        stale = {f.name for f in (out / "crops").iterdir()} - {Path(e["file"]).name for e in entries}
        for name in stale:  # crops of an earlier, larger build of this library
            (out / "crops" / name).unlink()
        manifest = {"format": 1, "config": asdict(config), "photos": len(photos), "dropped": dropped,
                    "mean": [round(float(v), 2) for v in np.mean(means, 0)],
                    "textures": entries}
        atomic_write_text(out / "ATTRIBUTION.md", attribution(entries))
        atomic_write_text(out / MANIFEST, json.dumps(manifest, indent=1) + "\n")
    return out


def attribution(entries: list[dict]) -> str:
    """The library's sources in words: one line per source with its licence, author and texture count."""
    by_source: dict[tuple, int] = {}
    for e in entries:
        key = (e["source"], e["url"], e["licence"], e["author"])
        by_source[key] = by_source.get(key, 0) + 1
    lines = ["# Texture library: sources and licences", ""]
    for (source, url, licence, author), n in sorted(by_source.items()):
        who = f", by {author}" if author else ""
        link = f" <{url}>" if url else ""
        lines.append(f"- {n} textures from {source}{link}{who}; licence {licence}")
    return "\n".join(lines) + "\n"
