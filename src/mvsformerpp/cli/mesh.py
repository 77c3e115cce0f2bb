"""``mvsformerpp mesh OUT -o mesh.ply``: a triangle mesh of a reconstruction (TSDF or screened Poisson)."""

from __future__ import annotations

import argparse

MAX_POISSON_DEPTH = 13


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
                   help="tsdf: voxel edge in scene units (default: 1.5 times the median size of a depth-map pixel "
                   "on the surface, coarser only where the grid would not fit in memory)")
    p.add_argument("--resolution", type=int, metavar="N",
                   help="tsdf: instead, N voxels along the longest side of the scene box")
    p.add_argument("--truncation", type=float, default=4.0, metavar="VOXELS",
                   help="tsdf: truncation in voxels, at most 100 (default 4)")
    p.add_argument("--min-conf", type=float, default=0.0, metavar="C",
                   help="tsdf: ignore depths at or below this confidence (default 0)")
    p.add_argument("--depth", type=int, default=10, help="poisson: octree depth (default 10)")
    p.add_argument("--watertight", action="store_true", help="poisson: keep the closed surface (no trimming)")
    p.add_argument("--max-distance", type=float, default=2.0, metavar="CELLS",
                   help="poisson: cut the surface farther than CELLS from every point (in the larger of the "
                        "point spacing and the octree cell; default 2, 0 = keep)")
    p.add_argument("--trim", type=float, default=0.0, metavar="PERCENT",
                   help="poisson: also cut the lowest-density PERCENT of vertices (default 0)")
    p.add_argument("--threads", type=int, default=1,
                   help="poisson: worker threads, at most the CPU cores this process may use (default 1)")
    p.add_argument("--device", default="cpu", help="tsdf: torch device (cpu, cuda)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run, on_memory_error="choose a larger --voxel (tsdf) or a smaller --depth (poisson)")


def run(args: argparse.Namespace) -> int:
    import math
    import os

    from mvsformerpp.errors import InputError
    from mvsformerpp.meshing.poisson import PoissonConfig
    from mvsformerpp.meshing.tsdf import TSDFConfig
    from mvsformerpp.pipelines.mesh import MeshConfig, make_mesh

    if args.voxel is not None and not (math.isfinite(args.voxel) and args.voxel > 0):
        raise InputError(f"--voxel must be a positive length in scene units, got {args.voxel}")
    if args.resolution is not None and args.resolution < 8:
        raise InputError(f"--resolution must be at least 8 voxels, got {args.resolution}")
    if args.method == "tsdf" and args.voxel is None and args.resolution is not None:
        import torch

        from mvsformerpp.inference.resolution import available_memory_bytes
        from mvsformerpp.meshing.tsdf import BYTES_PER_VOXEL

        need, have = BYTES_PER_VOXEL * args.resolution**3, available_memory_bytes(torch.device("cpu"))
        if need > have:
            raise InputError(f"--resolution {args.resolution} needs up to {need / 2**30:.1f} GB for the TSDF grid "
                             f"({BYTES_PER_VOXEL} bytes per voxel), more than the {have / 2**30:.1f} GB free; "
                             f"choose at most --resolution {int(round((have / BYTES_PER_VOXEL) ** (1 / 3), 6))}")
    if not 0 <= args.min_conf < 1:
        raise InputError(f"--min-conf must be a confidence in [0, 1), got {args.min_conf}")
    if not 1 <= args.depth <= MAX_POISSON_DEPTH:
        raise InputError(f"--depth must be 1 .. {MAX_POISSON_DEPTH} (each level multiplies the memory by about 4; "
                         f"depth 10 meshes a scene at 1/1000 of its size), got {args.depth}")
    if not 0 <= args.trim < 100:
        raise InputError(f"--trim must be a percentage in [0, 100), got {args.trim}")
    if not (math.isfinite(args.max_distance) and args.max_distance >= 0):
        raise InputError(f"--max-distance must be a number of cells >= 0 (0 keeps everything), got {args.max_distance}")
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if not 1 <= args.threads <= cores:
        raise InputError(f"--threads must be 1 .. {cores} (the CPU cores this process may use: MeshLab's threads "
                         f"spin while they wait, so more threads than cores stall), got {args.threads}")
    config = MeshConfig(
        method=args.method, device=args.device,
        tsdf=TSDFConfig(voxel=args.voxel, resolution=args.resolution, truncation=args.truncation,
                        min_confidence=args.min_conf),
        poisson=PoissonConfig(depth=args.depth, watertight=args.watertight,
                              max_distance=args.max_distance, trim=args.trim, threads=args.threads))
    make_mesh(args.folder, args.output, config, quiet=args.quiet)
    return 0
