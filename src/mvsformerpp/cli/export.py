"""``mvsformerpp export OUT --to colmap DIR``: hand a reconstruction to COLMAP or OpenMVS."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export",
        help="write a reconstruction as a COLMAP dense workspace (for COLMAP and OpenMVS)",
        description="Write OUT as a COLMAP dense workspace DIR: images/, sparse/ (pinhole cameras and poses), "
        "stereo/depth_maps/*.geometric.bin and normal_maps/ in COLMAP's array format, stereo/fusion.cfg, and the "
        "camera frustums as cameras.ply. COLMAP's stereo_fusion, poisson_mesher and OpenMVS's InterfaceCOLMAP "
        "read it.",
    )
    p.add_argument("folder", metavar="OUT", help="output folder of `mvsformerpp reconstruct`")
    p.add_argument("--to", choices=("colmap",), required=True, help="target format (colmap)")
    p.add_argument("target", metavar="DIR", help="workspace folder to create (must be empty or absent)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR, a workspace this command wrote before (the old one goes once the new one is "
                        "complete)")
    p.add_argument("--quiet", action="store_true", help="print nothing")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.export import export_colmap

    export_colmap(args.folder, args.target, overwrite=args.overwrite, quiet=args.quiet)
    return 0
