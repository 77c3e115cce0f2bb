"""``mvsformerpp view OUT``: the reconstruction in the browser (viser; the ``viewer`` extra)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view",
        help="look at a reconstruction in the browser: cloud, cameras, depth and confidence",
        description="Serve OUT in the browser: the fused cloud (a random subset within --max-points), the cameras "
        "as frustums with their photos, each view's depth and confidence maps, and a confidence slider that "
        "refilters the cloud. Works on a headless server: open the printed URL. Needs the 'viewer' extra: "
        "pip install 'mvsformerpp[viewer]'.",
    )
    p.add_argument("folder", metavar="OUT", help="output folder of `mvsformerpp reconstruct`")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--host", default="0.0.0.0", help="interface to listen on (default 0.0.0.0: all)")
    p.add_argument("--max-points", type=int, default=1_000_000, metavar="N",
                   help="point budget of the browser (default 1,000,000)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.errors import InputError
    from mvsformerpp.viewer.app import ViewerConfig, serve

    if not 0 < args.port < 65536:
        raise InputError(f"--port must be between 1 and 65535, got {args.port}")
    if args.max_points < 1:
        raise InputError(f"--max-points must be positive, got {args.max_points}")
    serve(args.folder, ViewerConfig(port=args.port, host=args.host, max_points=args.max_points))
    return 0
