"""``mvsformerpp reconstruct INPUT -o OUT``: depth maps and a fused point cloud from one command."""

from __future__ import annotations

import argparse
import logging

from mvsformerpp.pipelines.reconstruct import ReconstructConfig
from mvsformerpp.pipelines.sfm import SfMConfig

_DEFAULT = ReconstructConfig()


def add_model_args(p: argparse.ArgumentParser, default_preset: str) -> None:
    g = p.add_argument_group("network")
    g.add_argument("--preset", choices=("lite", "paper"), default=default_preset,
                   help=f"network preset (default: {default_preset}); 'lite' is a small network for CPU with "
                        "trained weights shipped in the package, 'paper' the official MVSFormer++ network "
                        "(with --checkpoint model_best.pth)")
    g.add_argument("--checkpoint", metavar="PATH",
                   help="weights matching the preset (default: the shipped weights for 'lite'; 'paper' has none)")
    g.add_argument("--device", default=_DEFAULT.device, help="torch device: cpu, cuda, cuda:1, ... (default: cpu)")
    g.add_argument("--precision", choices=("fp32", "bf16", "fp16"), default=_DEFAULT.precision,
                   help="autocast precision (default: fp32; bf16 is the reference's GPU setting)")


def add_run_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("reconstruction")
    g.add_argument("--max-size", type=int, default=_DEFAULT.max_size, metavar="PX",
                   help=f"cap on the longer side of the working resolution (default: {_DEFAULT.max_size}; "
                        "images are never upscaled and the aspect ratio is kept)")
    g.add_argument("--memory-gb", type=float, metavar="GB",
                   help="memory budget of one forward pass and of fusion (default: half of the free memory)")
    g.add_argument("--views", type=int, default=_DEFAULT.num_views, metavar="N",
                   help=f"views per depth map: the reference plus N-1 neighbours (default: {_DEFAULT.num_views})")
    g.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"),
                   help="override every view's depth range (scene units)")
    g.add_argument("--depth-format", choices=("auto", "interval", "max"), default=_DEFAULT.depth_format,
                   help="how to read a two-number depth line in MVSNet cam files: MIN INTERVAL, MIN MAX, or "
                        "auto (MAX when the second number is larger; default)")
    g.add_argument("--max-images", type=int, metavar="N",
                   help="use only N overlapping views: the first view and its best neighbours")
    g.add_argument("--interval-scale", type=float, default=_DEFAULT.interval_scale, metavar="S",
                   help="widen each view's depth range from its minimum by S (the reference's interval_scale; "
                        "the paper's DTU and Tanks-and-Temples runs use 1.06); not applied to --depth-range")
    g.add_argument("--num-depth", type=int, default=_DEFAULT.num_depth, metavar="N",
                   help=f"depth planes of the range, written to the output cams (default: {_DEFAULT.num_depth})")
    g.add_argument("--temperatures", type=float, nargs=4, default=_DEFAULT.temperatures, metavar="T",
                   help="per-stage softmax temperatures of the depth readout (default: 5 5 5 1, as the paper)")
    g.add_argument("--fusion", choices=("normal", "dynamic", "gipuma", "dtu", "tnt_intermediate", "tnt_advanced",
                                        "none"), default=_DEFAULT.fusion,
                   help=f"fusion preset (default: {_DEFAULT.fusion}; dtu, tnt_intermediate and tnt_advanced are the "
                        "paper's settings, see 'mvsformerpp fuse'); 'none' writes the depth maps only")
    g.add_argument("--conf", type=float, metavar="C",
                   help="fusion confidence threshold in [0, 1) (default: the one calibrated for the default weights "
                        "when they run, else the preset's)")
    g.add_argument("--fusion-resolution", choices=("working", "original"), default=_DEFAULT.fusion_resolution,
                   help="size of the depth maps fusion reads: the working resolution they were computed at "
                        "(default; photos larger than it do not multiply points and time), or as written")
    g.add_argument("--mask-dir", metavar="DIR",
                   help="object masks applied before fusion: one per photo, named like it or by view index "
                        "(DTU's mask/000.png and BlendedMVS's *_masked.jpg are recognised)")
    g.add_argument("--output-resolution", choices=("original", "working"), default=_DEFAULT.output_resolution,
                   help="size of the depth/confidence maps: each photo's own (default), or the working "
                        "resolution with images/ and cams/ scaled to match (smaller, faster to write)")
    g.add_argument("--cache-mb", type=int, default=_DEFAULT.cache_mb, metavar="MIB",
                   help=f"per-image feature cache budget (default: {_DEFAULT.cache_mb}; 0 disables it)")
    g.add_argument("--quiet", action="store_true", help="no progress bars (for scripts)")
    s = p.add_argument_group("structure from motion (a folder of photos)")
    s.add_argument("--camera-model", default=_DEFAULT.sfm.camera_model, metavar="MODEL",
                   help=f"COLMAP camera model to estimate (default: {_DEFAULT.sfm.camera_model}; e.g. PINHOLE, "
                        "RADIAL, OPENCV)")
    s.add_argument("--single-camera", action="store_true", help="all photos come from one camera with one lens")
    s.add_argument("--matcher", choices=("exhaustive", "sequential"), default=_DEFAULT.sfm.matcher,
                   help="exhaustive: all pairs (default); sequential: neighbours in name order (video frames)")
    s.add_argument("--sfm-max-size", type=int, default=_DEFAULT.sfm.max_image_size, metavar="PX",
                   help=f"longest photo side used for features (default: {_DEFAULT.sfm.max_image_size})")


def config_from_args(args: argparse.Namespace) -> ReconstructConfig:
    return ReconstructConfig(
        preset=args.preset, checkpoint=args.checkpoint, device=args.device, precision=args.precision,
        max_size=args.max_size, memory_gb=args.memory_gb, num_views=args.views,
        depth_range=tuple(args.depth_range) if args.depth_range else None, max_images=args.max_images,
        depth_format=args.depth_format,
        fusion=args.fusion, fusion_conf=args.conf, cache_mb=args.cache_mb, interval_scale=args.interval_scale,
        num_depth=args.num_depth,
        temperatures=tuple(args.temperatures),
        output_resolution=args.output_resolution, fusion_resolution=args.fusion_resolution, mask_dir=args.mask_dir,
        sfm=SfMConfig(camera_model=args.camera_model, single_camera=args.single_camera, matcher=args.matcher,
                      max_image_size=args.sfm_max_size),
    )


def print_summary(summary: dict, out) -> None:
    from mvsformerpp.viewer.folder import open_run
    from mvsformerpp.viewer.report import collect, summary_lines

    print("\n".join(summary_lines(collect(open_run(out)))))
    if summary["points"] is None:
        print(f"no fusion: run 'mvsformerpp fuse {out}' to fuse the depth maps")
    else:
        print(f"point cloud : {summary['outputs']['ply']}")
    print(f"depth images: {summary['outputs']['depth_vis']}")
    print(f"report      : {summary['outputs']['report']}")


def print_weights(description: str, quiet: bool) -> None:
    """Say which weights run (stdout); with --quiet only a warning about random weights (stderr)."""
    import sys

    if not quiet:
        print(description)
    elif "randomly initialised" in description:
        print(f"warning: {description}", file=sys.stderr)


def print_fusion(config, quiet: bool) -> None:
    """Say how the depth maps will be fused (stdout; nothing with --quiet)."""
    from mvsformerpp.pipelines.reconstruct import describe_fusion

    line = describe_fusion(config)
    if line and not quiet:
        print(line)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.reconstruct import describe_weights, reconstruct

    if args.quiet:
        logging.getLogger("mvsformerpp").setLevel(logging.WARNING)
    config = config_from_args(args)
    print_weights(describe_weights(config), args.quiet)
    print_fusion(config, args.quiet)
    summary = reconstruct(args.input, args.output, config, quiet=args.quiet)
    if not args.quiet:
        print_summary(summary, args.output)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "reconstruct",
        help="depth maps and a fused point cloud from photos, a COLMAP project or an MVSNet folder",
        description="Reconstruct INPUT: an MVSNet scene folder (images/, cams/, pair.txt), a COLMAP project "
                    "(distorted cameras are undistorted first), a Middlebury *_par.txt set, or a plain folder of "
                    "photos (structure-from-motion with pycolmap runs first). Writes per-view depth and "
                    "confidence maps, previews and OUT/fused.ply. Run the same command again to resume.",
    )
    p.add_argument("input", metavar="INPUT", help="scene folder or photo folder")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output folder")
    add_model_args(p, default_preset=_DEFAULT.preset)
    add_run_args(p)
    p.set_defaults(func=run)
