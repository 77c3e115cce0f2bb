"""``mvsformerpp fuse DIR -o cloud.ply``: fusion alone, on depth maps that already exist."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from mvsformerpp.fusion.config import PRESETS

    p = sub.add_parser(
        "fuse",
        help="fuse existing depth maps into a point cloud",
        description="Fuse the depth maps of a scene folder (images/, cams/, pair.txt, depth_est/, "
        "confidence/: the layout reconstruct and MVSNet-family test scripts write) into a binary PLY.",
    )
    p.add_argument("folder", help="scene folder with depth_est/ (and confidence/)")
    p.add_argument("-o", "--output", help="output PLY (default FOLDER/fused.ply)")
    p.add_argument("--fusion", "--preset", dest="preset", default="normal", choices=sorted(PRESETS),
                   help="filter or named preset (dtu and tnt_* are the reference's settings)")
    p.add_argument("--conf", type=float, help="confidence threshold")
    p.add_argument("--disp", type=float, help="reprojection (normal) or disparity (gipuma) threshold")
    p.add_argument("--num-consistent", type=int, help="consistent source views needed")
    p.add_argument("--num-src-views", type=int, help="source views checked per reference view")
    p.add_argument("--mask-dir", metavar="DIR",
                   help="object masks: depths outside them are dropped before fusion (one per photo, named like "
                        "it or by view index; DTU's mask/000.png and BlendedMVS's *_masked.jpg are recognised)")
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    p.add_argument("--memory-gb", type=float, metavar="GB",
                   help="memory budget: depth maps are read on demand and cached within it, points are "
                        "written as they are produced (default: half of the free memory)")
    p.add_argument("--max-size", type=int, metavar="PX",
                   help="fuse depth maps whose longer side exceeds PX at PX (default: the working resolution a "
                        "reconstruct run records in config.json, so maps upsampled to large photos fuse at the size "
                        "they were computed at; 0: at the size they are stored)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from mvsformerpp.errors import InputError
    from mvsformerpp.fusion import get_config
    from mvsformerpp.pipelines.fuse import fuse
    from mvsformerpp.utils.device import parse_device
    from mvsformerpp.utils.output_guard import claim_output_file, writing

    if not Path(args.folder).is_dir():
        raise InputError("no such folder", args.folder)
    conf = args.conf
    if conf is None:
        conf = shipped_weights_conf(Path(args.folder), get_config(args.preset).method)
        if conf is not None and not args.quiet:
            print(f"confidence threshold {conf:g}: calibrated for the default weights that made these depth maps "
                  "(--conf sets another)")
    config = get_config(args.preset, conf_threshold=conf, disp_threshold=args.disp,
                        num_consistent=args.num_consistent, num_src_views=args.num_src_views)
    parse_device(args.device)
    out = Path(args.output) if args.output else Path(args.folder) / "fused.ply"
    if args.max_size is not None and args.max_size != 0 and args.max_size < 16:
        raise InputError(f"--max-size must be at least 16 pixels (or 0: the stored size), got {args.max_size}")
    max_size = working_size(Path(args.folder)) if args.max_size is None else (args.max_size or None)
    with claim_output_file(out, b"ply", "PLY"), writing(out):
        fuse(args.folder, out, config, device=args.device, quiet=args.quiet, memory_gb=args.memory_gb,
             mask_dir=args.mask_dir, max_size=max_size)
    return 0


def working_size(folder) -> int | None:
    """The working resolution (longer side) a reconstruct run of ``folder`` computed its depth maps at, when
    its config.json says so and asks fusion to read them at it (the default), else None."""
    import json

    try:
        record = json.loads((folder / "config.json").read_text())
        size = record["resolved"]["long_side"]
        wanted = record["config"].get("fusion_resolution", "original")
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return int(size) if wanted == "working" and isinstance(size, int) else None


def shipped_weights_conf(folder, method: str) -> float | None:
    """The threshold calibrated for the shipped weights when ``reconstruct`` made ``folder`` with them
    (its config.json says so), else None."""
    import json

    from mvsformerpp.models import shipped

    try:
        cfg = json.loads((folder / "config.json").read_text())["config"]
    except (OSError, ValueError, KeyError, TypeError):
        return None  # not a reconstruct output folder: the preset's threshold
    if not isinstance(cfg, dict) or not shipped.runs_shipped(cfg.get("preset"), cfg.get("checkpoint")):
        return None
    return shipped.calibrated_conf(method)
