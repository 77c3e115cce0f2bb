"""``mvsformerpp mesh OUT -o mesh.ply``: a triangle mesh of a reconstruction (TSDF or screened Poisson)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "mesh",
        help="triangle mesh from the depth maps (TSDF) or the fused cloud (screened Poisson)",
        description="Mesh a reconstruct output folder. tsdf: confidence-weighted TSDF integration of the depth "
        "maps and marching cubes (torch; --device cuda where there is one). poisson: screened Poisson on "
        "OUT/fused.ply and its normals. Needs the 'mesh' extra: pip install 'mvsformerpp[mesh]'.",
    )
    p.add_argument("folder", metavar="OUT", help="output folder of `mvsformerpp reconstruct`")
    p.add_argument("-o", "--output", required=True, metavar="MESH.ply", help="mesh to write (binary PLY)")
    p.add_argument("--method", choices=("tsdf", "poisson"), default="tsdf", help="default: tsdf")
    p.add_argument("--voxel", type=float, metavar="V",
                   help="tsdf: voxel edge in scene units (default: the scene box's longest side / --resolution)")
    p.add_argument("--resolution", type=int, default=256, metavar="N",
                   help="tsdf: voxels along the scene box's longest side when --voxel is not given (default 256)")
    p.add_argument("--truncation", type=float, default=4.0, metavar="VOXELS", help="tsdf: truncation (default 4)")
    p.add_argument("--min-conf", type=float, default=0.0, metavar="C",
                   help="tsdf: ignore depths at or below this confidence (default 0)")
    p.add_argument("--depth", type=int, default=10, help="poisson: octree depth (default 10)")
    p.add_argument("--watertight", action="store_true", help="poisson: keep the closed surface (no trimming)")
    p.add_argument("--trim", type=float, default=10.0, metavar="PERCENT",
                   help="poisson: cut the lowest-density PERCENT of vertices (default 10)")
    p.add_argument("--threads", type=int, default=1, help="poisson: worker threads (default 1)")
    p.add_argument("--device", default="cpu", help="tsdf: torch device (cpu, cuda)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mvsformerpp.errors import InputError
    from mvsformerpp.meshing.poisson import PoissonConfig
    from mvsformerpp.meshing.tsdf import TSDFConfig
    from mvsformerpp.pipelines.mesh import MeshConfig, make_mesh

    if args.voxel is not None and args.voxel <= 0:
        raise InputError(f"--voxel must be positive, got {args.voxel}")
    if args.resolution < 8:
        raise InputError(f"--resolution must be at least 8, got {args.resolution}")
    config = MeshConfig(
        method=args.method, device=args.device,
        tsdf=TSDFConfig(voxel=args.voxel, resolution=args.resolution, truncation=args.truncation,
                        min_confidence=args.min_conf),
        poisson=PoissonConfig(depth=args.depth, watertight=args.watertight, trim=args.trim, threads=args.threads))
    make_mesh(args.folder, args.output, config, quiet=args.quiet)
    return 0
