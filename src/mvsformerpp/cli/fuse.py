"""``mvsformerpp fuse DIR -o cloud.ply``: fusion alone, on depth maps that already exist."""

from __future__ import annotations

import argparse
from pathlib import Path

from mvsformerpp.errors import InputError
from mvsformerpp.fusion.choice import choose_fusion
from mvsformerpp.fusion.config import PRESETS
from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig, fusion_overrides
from mvsformerpp.utils.config_flags import add_config_flags

SHARED_FIELDS = ("fusion", "fusion_conf", "fusion_disp", "fusion_num_consistent", "fusion_num_src_views", "mask_dir",
                 "device", "memory_gb")
"""The settings ``fuse`` shares with ``reconstruct`` (same flags, same help)."""


def register(sub: argparse._SubParsersAction) -> None:
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
    p.add_argument("--max-size", type=int, metavar="PX",
                   help="fuse depth maps whose longer side exceeds PX at PX (default: the working resolution a "
                        "reconstruct run records in config.json, so maps upsampled to large photos fuse at the size "
                        "they were computed at; 0: at the size they are stored)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run, on_memory_error="lower --memory-gb or --max-size")


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.fuse import RECORDED, fuse, recorded_calibration
    from mvsformerpp.utils.device import parse_device

    if not Path(args.folder).is_dir():
        raise InputError("no such folder", args.folder)
    if args.fusion == "none":
        raise InputError(f"fuse --fusion none would fuse nothing; choose a fusion preset ({', '.join(PRESETS)})")
    choice = choose_fusion(args.fusion, recorded_calibration(args.folder), args.fusion_conf, **fusion_overrides(args))
    if choice.source == "calibrated" and not args.quiet:
        print(f"confidence threshold {choice.settings.conf_threshold:g}: calibrated for the default weights that "
              "made these depth maps (--conf sets another)")
    parse_device(args.device)
    fuse(args.folder, args.output, choice.settings, device=args.device, quiet=args.quiet, memory_gb=args.memory_gb,
         mask_dir=args.mask_dir, max_size=RECORDED if args.max_size is None else args.max_size)
    return 0
