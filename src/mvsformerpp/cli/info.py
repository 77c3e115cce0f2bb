"""``mvsformerpp info SCENE``: detect a scene's layout and print its views, sizes, depth ranges, neighbours."""

from __future__ import annotations

import argparse
import json

from mvsformerpp.models.presets import RECONSTRUCT_PRESETS
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "info",
        help="show a scene: layout, views, resolutions, depth ranges, neighbours",
        description="Detect the layout of SCENE (MVSNet, COLMAP, Middlebury, DTU, BlendedMVS, Tanks and Temples) "
        "and summarise it.",
    )
    p.add_argument("scene", metavar="SCENE", help="scene folder or camera file")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--views", action="store_true", help="also list every view (size, focal, depth range, neighbours)")
    p.add_argument("--depth-range", nargs=2, type=float, metavar=("MIN", "MAX"), help="override every depth range")
    p.add_argument("--num-neighbors", type=int, help="cap the neighbour lists (default 10)")
    p.add_argument("--depth-format", choices=["auto", "interval", "max"], default="auto",
                   help="how to read a two-number cam depth line: min+interval, min+max, or guess (default)")
    p.add_argument("--scan", help="DTU scan to show (e.g. scan1) when the layout holds several")
    p.add_argument("--short-range", action="store_true", help="Tanks and Temples: use short_range_cameras")
    p.add_argument("--preset", choices=RECONSTRUCT_PRESETS, default=ReconstructConfig.preset,
                   help=f"the network whose reconstruct defaults the stage-1 line assumes (default "
                        f"{ReconstructConfig.preset})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.io.detect import detect_layout, load_scene
    from mvsformerpp.io.summary import format_summary, summarize_scene

    layout = detect_layout(args.scene)
    scene = load_scene(
        args.scene,
        layout=layout,
        depth_range=tuple(args.depth_range) if args.depth_range else None,
        num_neighbors=args.num_neighbors,
        depth_format=args.depth_format,
        scan=args.scan,
        short_range=args.short_range,
    )
    summary = summarize_scene(scene, layout, per_view=args.views)
    summary["stage1_parallax"] = _stage1_parallax(scene, args.preset)
    if layout in ("mvsnet", "tnt") and not args.depth_range:
        from pathlib import Path

        from mvsformerpp.io.detect import mvsnet_cam_dir
        from mvsformerpp.io.mvsnet import depth_line_forms

        root = Path(args.scene) if Path(args.scene).is_dir() else Path(args.scene).parent
        cam_dir = mvsnet_cam_dir(root)
        if cam_dir is not None:
            summary["depth_lines"] = depth_line_forms(cam_dir, args.depth_format)
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary))
    return 0


def _stage1_parallax(scene, preset: str):
    """What stage 1's planes resolve with ``reconstruct --preset PRESET``'s defaults on this machine (CPU)."""
    import torch

    from mvsformerpp.pipelines.run_plan import stage1_parallax

    return stage1_parallax(scene, ReconstructConfig(preset=preset), torch.device("cpu"))
