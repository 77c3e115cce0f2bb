"""``mvsformerpp textures PHOTOS -o LIBRARY``: a texture library of real photographs for synthetic training."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from mvsformerpp.pipelines.texture_library import LibraryConfig

    d = LibraryConfig()
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
    p.add_argument("--crop", type=int, default=d.crop, help=f"crop side in pixels (default {d.crop})")
    p.add_argument("--crops-per-scale", type=int, default=d.crops_per_scale,
                   help=f"random crops per photo and scale (default {d.crops_per_scale})")
    p.add_argument("--scales", type=int, default=d.max_scales,
                   help=f"scales per photo: 1, 1/2, 1/4, ... (default {d.max_scales})")
    p.add_argument("--min-contrast", type=float, default=d.min_contrast,
                   help=f"least grey-level standard deviation (0-255) of a kept crop (default {d.min_contrast:g})")
    p.add_argument("--max-per-source", type=int, metavar="N",
                   help="at most N textures from the photos of one source.json (a sample of all its photos; "
                   "default: no cap)")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of the photos' order and the crop positions")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from mvsformerpp.errors import InputError
    from mvsformerpp.pipelines.texture_library import LibraryConfig, build_texture_library

    if not 32 <= args.crop <= 4096 or args.crops_per_scale < 1 or not 1 <= args.scales <= 8:
        raise InputError(f"need 32 <= --crop <= 4096, --crops-per-scale >= 1 and 1 <= --scales <= 8, got --crop "
                         f"{args.crop} --crops-per-scale {args.crops_per_scale} --scales {args.scales}")
    if not 0 <= args.min_contrast < 128 or args.seed < 0 or (args.max_per_source is not None
                                                            and args.max_per_source < 1):
        raise InputError(f"need 0 <= --min-contrast < 128, --seed >= 0 and --max-per-source >= 1, got "
                         f"{args.min_contrast:g}, {args.seed} and {args.max_per_source}")
    config = LibraryConfig(crop=args.crop, crops_per_scale=args.crops_per_scale, max_scales=args.scales,
                           min_contrast=args.min_contrast,
                           max_per_source=args.max_per_source, seed=args.seed)
    out = build_texture_library(config, args.photos, args.output, progress=not args.quiet)
    manifest = json.loads((out / "manifest.json").read_text())
    print(f"wrote {len(manifest['textures'])} textures from {manifest['photos']} photos to {out} "
          f"(dropped: {manifest['dropped']})")
    return 0
