"""A texture library on disk: crops of real photographs with their source and licence, for the generator.

Layout (written by :func:`mvsformerpp.pipelines.texture_library.build_texture_library`)::

    LIBRARY/manifest.json         {"format": 1, "textures": [{"file", "photo", "source", "url", "licence",
                                   "author", "scale", "box", "mean", "std"}, ...], "photos": ..., "dropped": ...}
    LIBRARY/crops/000000.png      one RGB texture per entry (at most ``crop`` pixels a side)
    LIBRARY/ATTRIBUTION.md        the sources and licences in words

``synthetic_options: {textures: LIBRARY}`` in a training recipe (or ``mvsformerpp synth --textures``) makes
the ``train`` style's photo surfaces draw from it instead of scikit-image's sample photographs. Textures are
decoded on first use and their mip pyramids kept in a per-process cache, so a library of thousands of crops
costs memory only for the ones the current scenes show.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from pathlib import Path

import numpy as np

from mvsformerpp.errors import InputError
from mvsformerpp.io.images import read_image
from mvsformerpp.synth.mipmaps import pyramid

MANIFEST = "manifest.json"
FORMAT = 1
MIN_TEXTURES = 5
"""A library needs at least this many textures (a handful of photos would repeat in every scene)."""
CACHE_TEXTURES = 256
"""Mip pyramids a process keeps decoded (about 0.6 MB each at 384 px)."""


def read_manifest(library: str | Path) -> dict:
    """The manifest of ``library``, checked: format, entries, and every crop file present."""
    root = Path(library)
    path = root / MANIFEST
    if not root.is_dir():
        raise InputError("texture library not found (build one with: mvsformerpp textures PHOTOS -o LIBRARY)", root)
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"not a texture library: no {MANIFEST} (build one with: mvsformerpp textures PHOTOS -o "
                         "LIBRARY)", root) from None
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read the texture library's manifest ({e}); build the library again", path) from e
    entries = manifest.get("textures") if isinstance(manifest, dict) else None
    if manifest.get("format") != FORMAT or not isinstance(entries, list):
        raise InputError(f"not a texture library manifest of format {FORMAT}; build the library again", path)
    if len(entries) < MIN_TEXTURES:
        raise InputError(f"the texture library holds {len(entries)} textures, fewer than {MIN_TEXTURES}; build it "
                         "from more photos", root)
    missing = [e.get("file") for e in entries if not (root / str(e.get("file"))).is_file()]
    if missing:
        raise InputError(f"{len(missing)} texture files of the manifest are missing (e.g. {missing[0]}); build the "
                         "library again", root)
    return manifest


class TextureLibrary:
    """The textures of a library as a sequence of mip pyramids (what :class:`~mvsformerpp.synth.render.SynthScene`
    ``textures`` holds), decoded lazily and kept in a least-recently-used cache of :data:`CACHE_TEXTURES`."""

    def __init__(self, library: str | Path):
        self.root = Path(library)
        self.entries: list[dict] = read_manifest(self.root)["textures"]
        self._cache: OrderedDict[int, list[np.ndarray]] = OrderedDict()

    def __len__(self) -> int:
        return len(self.entries)

    def __getitem__(self, index: int) -> list[np.ndarray]:
        i = int(index) % len(self.entries)
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        levels = pyramid(read_image(self.root / self.entries[i]["file"]))
        self._cache[i] = levels
        while len(self._cache) > CACHE_TEXTURES:
            self._cache.popitem(last=False)
        return levels

    def __getstate__(self) -> dict:  # worker processes decode their own textures
        return {"root": self.root, "entries": self.entries}

    def __setstate__(self, state: dict) -> None:
        self.root, self.entries, self._cache = state["root"], state["entries"], OrderedDict()

    def describe(self) -> str:
        licences = sorted({str(e.get("licence")) for e in self.entries})
        return f"texture library {self.root} ({len(self)} textures; {', '.join(licences)})"
