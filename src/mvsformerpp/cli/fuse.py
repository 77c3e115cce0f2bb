"""``mvsformerpp fuse DIR -o cloud.ply``: fusion alone, on depth maps that already exist."""

from __future__ import annotations

import argparse

SHARED_FIELDS = ("fusion", "fusion_conf", "mask_dir", "device", "memory_gb")
"""The settings ``fuse`` shares with ``reconstruct`` (same flags, same help)."""


def register(sub: argparse._SubParsersAction) -> None:
    from mvsformerpp.fusion.config import FusionConfig
    from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
    from mvsformerpp.utils.config_flags import add_config_flags

    p = sub.add_parser(
        "fuse",
        help="fuse existing depth maps into a point cloud",
        description="Fuse the depth maps of a scene folder (images/, cams/, pair.txt, depth_est/, "
        "confidence/: the layout reconstruct and MVSNet-family test scripts write) into a binary PLY. "
        "Settings left out come from the fusion preset.",
    )
    p.add_argument("folder", help="scene folder with depth_est/ (and confidence/)")
    p.add_argument("-o", "--output", help="output PLY (default FOLDER/fused.ply)")
    add_config_flags(p, ReconstructConfig, SHARED_FIELDS, groups={"network": p, "reconstruction": p})
    add_config_flags(p, FusionConfig, ("disp_threshold", "num_consistent", "num_src_views"),
                     disp_threshold=None, num_consistent=None, num_src_views=None,
                     default_notes=dict.fromkeys(("disp_threshold", "num_consistent", "num_src_views"),
                                                 "the preset's"))
    p.add_argument("--max-size", type=int, metavar="PX",
                   help="fuse depth maps whose longer side exceeds PX at PX (default: the working resolution a "
                        "reconstruct run records in config.json, so maps upsampled to large photos fuse at the size "
                        "they were computed at; 0: at the size they are stored)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run, on_memory_error="lower --memory-gb or --max-size")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from mvsformerpp.errors import InputError
    from mvsformerpp.fusion import get_config
    from mvsformerpp.pipelines.fuse import RECORDED, fuse, recorded_calibrated_conf
    from mvsformerpp.utils.device import parse_device

    if not Path(args.folder).is_dir():
        raise InputError("no such folder", args.folder)
    if args.fusion == "none":
        raise InputError("fuse --fusion none would fuse nothing; choose a fusion preset (normal, dynamic, gipuma, "
                         "dtu, tnt_intermediate, tnt_advanced)")
    conf = args.fusion_conf
    if conf is None:
        conf = recorded_calibrated_conf(args.folder, get_config(args.fusion).method)
        if conf is not None and not args.quiet:
            print(f"confidence threshold {conf:g}: calibrated for the default weights that made these depth maps "
                  "(--conf sets another)")
    config = get_config(args.fusion, conf_threshold=conf, disp_threshold=args.disp_threshold,
                        num_consistent=args.num_consistent, num_src_views=args.num_src_views)
    parse_device(args.device)
    if args.max_size is not None and args.max_size != 0 and args.max_size < 16:
        raise InputError(f"--max-size must be at least 16 pixels (or 0: the stored size), got {args.max_size}")
    max_size = RECORDED if args.max_size is None else (args.max_size or None)
    fuse(args.folder, args.output, config, device=args.device, quiet=args.quiet, memory_gb=args.memory_gb,
         mask_dir=args.mask_dir, max_size=max_size)
    return 0
