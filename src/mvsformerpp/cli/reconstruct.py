"""``mvsformerpp reconstruct INPUT -o OUT``: depth maps and a fused point cloud from one command."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys

from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
from mvsformerpp.utils.config_flags import add_config_flags
from mvsformerpp.utils.config_flags import config_from_args as _from_args

NETWORK_FIELDS = ("preset", "checkpoint", "device", "precision", "backend", "onnx_model")


def add_model_args(p: argparse.ArgumentParser, default_preset: str) -> None:
    """The network's flags (``ReconstructConfig``'s network group)."""
    add_config_flags(p, ReconstructConfig, NETWORK_FIELDS, groups={}, preset=default_preset)


def add_run_args(p: argparse.ArgumentParser) -> None:
    """Every other flag of ``ReconstructConfig`` (reconstruction and structure from motion), and --quiet."""
    groups = {g.title: g for g in p._action_groups}
    names = [f.name for f in dataclasses.fields(ReconstructConfig) if f.name not in NETWORK_FIELDS]
    add_config_flags(p, ReconstructConfig, names, groups=groups)
    (groups.get("reconstruction") or p).add_argument("--quiet", action="store_true",
                                                     help="no progress bars (for scripts)")


def config_from_args(args: argparse.Namespace) -> ReconstructConfig:
    return _from_args(ReconstructConfig, args)


def print_summary(summary: dict, out) -> None:
    from mvsformerpp.io.output_folder import open_run
    from mvsformerpp.viewer.report import collect, summary_lines

    print("\n".join(summary_lines(collect(open_run(out)))))
    if summary["points"] is None:
        print(f"no fusion: run 'mvsformerpp fuse {out}' to fuse the depth maps")
    else:
        print(f"point cloud : {summary['outputs']['ply']}")
    print(f"depth images: {summary['outputs']['depth_vis']}")
    print(f"report      : {summary['outputs']['report']}")


def print_intro(config: ReconstructConfig, quiet: bool) -> None:
    """Say which weights run and how the depth maps will be fused (stdout); with --quiet only a warning
    about random weights (stderr)."""
    from mvsformerpp.pipelines.network import run_weights

    weights = run_weights(config)
    if not quiet:
        print(weights.description)
        fusion = config.fusion_choice(weights.calibrated_conf)
        if fusion is not None:
            print(fusion.line)
    elif weights.is_random:
        print(f"warning: {weights.description}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.reconstruct import reconstruct

    if args.quiet:
        logging.getLogger("mvsformerpp").setLevel(logging.WARNING)
    config = config_from_args(args)
    print_intro(config, args.quiet)
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
    add_model_args(p, default_preset=ReconstructConfig.preset)
    add_run_args(p)
    p.set_defaults(func=run, on_memory_error="lower --max-size or --memory-gb")
