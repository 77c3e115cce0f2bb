"""``mvsformerpp textures PHOTOS -o LIBRARY``: a texture library of real photographs for synthetic training."""

from __future__ import annotations

import argparse
import json

from mvsformerpp.pipelines.texture_library import FLAGS, LibraryConfig, build_texture_library
from mvsformerpp.utils.config_flags import add_config_flags, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "textures",
        help="build a texture library of real photographs for synthetic training",
        description="Cut square crops at several scales from a folder of photographs, drop flat crops and "
        "near-duplicates, and write LIBRARY/crops/*.png with a manifest (photo, source, licence, box, colour "
        "statistics per crop) and ATTRIBUTION.md. Every photo needs a source.json in its folder or above "
        '({"licence": "CC0-1.0", "source": "...", "url": "...", "author": "..."}); accepted licences: CC0-1.0, '
        "public-domain, MIT, CC-BY-<version>. Train on it with --set 'synthetic_options={textures: LIBRARY}' "
        "(besides the recipe's other options), or render with mvsformerpp synth --style train --textures LIBRARY.",
    )
    p.add_argument("photos", help="folder of photographs (searched at any depth)")
    p.add_argument("-o", "--output", required=True, help="library folder (new, or a library to rebuild)")
    add_config_flags(p, LibraryConfig, FLAGS)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(LibraryConfig, args)
    out = build_texture_library(config, args.photos, args.output, progress=not args.quiet)
    manifest = json.loads((out / "manifest.json").read_text())
    print(f"wrote {len(manifest['textures'])} textures from {manifest['photos']} photos to {out} "
          f"(dropped: {manifest['dropped']})")
    return 0
