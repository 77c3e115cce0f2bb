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
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from mvsformerpp.errors import InputError
from mvsformerpp.io.images import IMAGE_SUFFIXES, image_size, read_image
from mvsformerpp.synth.texture_library import MANIFEST, MIN_TEXTURES
from mvsformerpp.synth.writer import save_png
from mvsformerpp.utils.atomic import atomic_write_text
from mvsformerpp.utils.config_flags import flag_name
from mvsformerpp.utils.output_guard import claim_output_folder

LICENCES = ("CC0-1.0", "public-domain", "MIT")
"""Licences a library accepts, besides ``CC-BY-<version>`` (attribution only: no NC, SA or ND terms)."""
SOURCE_FILE = "source.json"


@dataclass(frozen=True)
class LibraryConfig:
    """How crops are cut from the photos (saved in the manifest); the ``textures`` command's flags."""

    crop: int = 384
    """Side of a crop in pixels (the generator's textures are at most 384 px: ``synth.mipmaps.MAX_SIDE``)."""
    crops_per_scale: int = 4
    """Random crops per photo and scale; a photo smaller than ``crop`` (at least ``min_side``) is one texture."""
    max_scales: int = field(default=4, metadata={"flag": "--scales"})
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
    max_per_source: int | None = field(default=None, metadata={"metavar": "N"})
    """Most textures one ``source.json`` contributes, spread over all of its photos (each gives at most its
    share, a random choice among its crops): a capture of one object in dozens of views would otherwise fill
    the library. None: no cap."""
    seed: int = 0
    """Seed of the photos' order and the crop positions."""

    def __post_init__(self) -> None:
        def name(f: str) -> str:
            return flag_name(LibraryConfig, f)

        if not 32 <= self.crop <= 4096 or self.crops_per_scale < 1 or not 1 <= self.max_scales <= 8:
            raise InputError(f"need 32 <= {name('crop')} <= 4096, {name('crops_per_scale')} >= 1 and 1 <= "
                             f"{name('max_scales')} <= 8, got {self.crop}, {self.crops_per_scale} and "
                             f"{self.max_scales}")
        if not 0 <= self.min_contrast < 128 or self.seed < 0 or (self.max_per_source is not None
                                                                 and self.max_per_source < 1):
            raise InputError(f"need 0 <= {name('min_contrast')} < 128, {name('seed')} >= 0 and "
                             f"{name('max_per_source')} >= 1, got {self.min_contrast:g}, {self.seed} and "
                             f"{self.max_per_source}")


FLAGS = ("crop", "crops_per_scale", "max_scales", "min_contrast", "max_per_source", "seed")
"""The :class:`LibraryConfig` fields with a flag of the ``textures`` command."""


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
    root = Path(photos_dir)
    photos = list_photos(root)
    usable = _usable_photos(photos, root, config)
    rng = np.random.default_rng(config.seed)
    usable = [usable[i] for i in rng.permutation(len(usable))]
    with claim_output_folder(out, inputs=[root], kind="textures", reuse=True) as out:
        (out / "crops").mkdir(exist_ok=True)
        library = _Crops(out, root, config, dropped_small=len(photos) - len(usable))
        photos_of: dict[str, int] = {}
        for _, info in usable:
            photos_of[info["source"]] = photos_of.get(info["source"], 0) + 1
        for p, info in tqdm(usable, desc="textures", unit="photo", disable=not progress):
            crops = list(_crops(read_image(p), config, rng))
            cap = info.get("max_textures", config.max_per_source)
            share = len(crops) if cap is None else -(-cap // photos_of[info["source"]])
            taken = 0
            for k in rng.permutation(len(crops)):
                if taken >= share or (cap is not None and library.per_source.get(info["source"], 0) >= cap):
                    library.dropped["over_cap"] += 1
                    continue
                taken += library.add(*crops[k], p, info)
        library.finish(len(photos))
    return out


def _usable_photos(photos: list[Path], root: Path, config: LibraryConfig) -> list[tuple[Path, dict]]:
    """(photo, its source) of the photos at least ``min_side`` on their shorter side, each checked: its
    licence, and that it reads (before anything is written)."""
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
    return usable


class _Crops:
    """The crops of a library being written into ``out``: their entries, hashes and mean colours (to drop
    near-duplicates), the count per source and the counts of crops dropped, by reason."""

    def __init__(self, out: Path, root: Path, config: LibraryConfig, dropped_small: int):
        self.out, self.root, self.config = out, root, config
        self.entries: list[dict] = []
        self.hashes: list[np.ndarray] = []
        self.means: list[np.ndarray] = []
        self.per_source: dict[str, int] = {}
        self.dropped = {"flat": 0, "duplicate": 0, "too_small": dropped_small, "over_cap": 0}

    def add(self, crop: np.ndarray, scale: float, box: tuple, photo: Path, info: dict) -> bool:
        """Write ``crop`` unless it is flat or a near-duplicate of one kept; whether it was kept."""
        config = self.config
        grey = crop.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
        if grey.std() < config.min_contrast:
            self.dropped["flat"] += 1
            return False
        mean = crop.reshape(-1, 3).mean(0)
        code = average_hash(grey)
        if self.entries and np.any(((np.asarray(self.hashes) != code).sum(1) <= config.duplicate_bits)
                                   & (np.linalg.norm(np.asarray(self.means) - mean, axis=1) < config.duplicate_colour)):
            self.dropped["duplicate"] += 1
            return False
        name = f"crops/{len(self.entries):06d}.png"
        save_png(self.out / name, crop)
        self.hashes.append(code)
        self.means.append(mean)
        self.per_source[info["source"]] = self.per_source.get(info["source"], 0) + 1
        self.entries.append({"file": name, "photo": photo.relative_to(self.root).as_posix(), "source": info["source"],
                             "url": info.get("url", ""), "licence": info["licence"],
                             "author": info.get("author", ""), "scale": scale, "box": list(box),
                             "size": [int(crop.shape[1]), int(crop.shape[0])],
                             "mean": [round(float(v), 2) for v in mean],
                             "std": [round(float(v), 2) for v in crop.reshape(-1, 3).std(0)]})
        return True

    def finish(self, photos: int) -> None:
        """Check there are enough textures, remove an earlier build's extra crops, write the attribution and
        the manifest (last)."""
        out, entries = self.out, self.entries
        if len(entries) < MIN_TEXTURES:
            raise InputError(f"only {len(entries)} textures survived (fewer than {MIN_TEXTURES}; dropped: "
                             f"{self.dropped}); give more photos, or lower --min-contrast", self.root)
        stale = {f.name for f in (out / "crops").iterdir()} - {Path(e["file"]).name for e in entries}
        for name in stale:  # crops of an earlier, larger build of this library
            (out / "crops" / name).unlink()
        manifest = {"format": 1, "config": asdict(self.config), "photos": photos, "dropped": self.dropped,
                    "mean": [round(float(v), 2) for v in np.mean(self.means, 0)],
                    "textures": entries}
        atomic_write_text(out / "ATTRIBUTION.md", attribution(entries))
        atomic_write_text(out / MANIFEST, json.dumps(manifest, indent=1) + "\n")


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
