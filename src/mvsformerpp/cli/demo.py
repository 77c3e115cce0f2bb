"""``mvsformerpp demo``: the bundled temple, end to end, with the lite network and its shipped weights."""

from __future__ import annotations

import argparse
import dataclasses

from mvsformerpp.cli.reconstruct import add_model_args, print_intro, print_summary


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.pipelines.demo import DEMO_CONFIG, run_demo, temple_dir

    config = dataclasses.replace(DEMO_CONFIG, preset=args.preset, checkpoint=args.checkpoint, device=args.device,
                                 precision=args.precision, backend=args.backend, onnx_model=args.onnx_model,
                                 max_size=args.max_size, max_images=args.max_images)
    if not args.quiet:
        print(f"Reconstructing the Middlebury temple ({temple_dir()}; see README.txt there for its credits)")
    print_intro(config, args.quiet)
    summary = run_demo(args.output, config, quiet=args.quiet)
    if not args.quiet:
        print_summary(summary, args.output)
    return 0


def register(subparsers) -> None:
    from mvsformerpp.pipelines.demo import DEMO_CONFIG
    from mvsformerpp.pipelines.reconstruct_config import ReconstructConfig
    from mvsformerpp.utils.config_flags import add_config_flags

    p = subparsers.add_parser("demo", help="reconstruct the bundled Middlebury temple end to end",
                              description="Reconstruct the bundled 16-view Middlebury temple with the lite network "
                                          "and print where the point cloud and depth images are.")
    p.add_argument("-o", "--output", default="mvsformerpp-demo", metavar="OUT",
                   help="output folder (default: ./mvsformerpp-demo)")
    add_model_args(p, default_preset="lite")
    add_config_flags(p, ReconstructConfig, ("max_size", "max_images"), max_size=DEMO_CONFIG.max_size)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run, on_memory_error="lower --max-size")
