"""``mesh``: a triangle mesh from a reconstruction's depth maps (TSDF) or fused cloud (screened Poisson).

* ``tsdf``: the depth maps in ``OUT/depth_est`` (confidence as weight) integrated into a voxel grid on
  the chosen device (:mod:`mvsformerpp.meshing.tsdf`), the zero level set extracted with marching cubes;
  coloured from the photos. Keeps thin structures that fusion filters keep, fills nothing.
* ``poisson``: screened Poisson on ``OUT/fused.ply`` with its normals (:mod:`mvsformerpp.meshing.poisson`);
  smooth and closed (``watertight``) or trimmed where no sample supports it.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from tqdm import tqdm

from mvsformerpp.errors import InputError
from mvsformerpp.fusion import make_views
from mvsformerpp.inference import resolution
from mvsformerpp.io.depth_folder import load_depth_folder
from mvsformerpp.io.output_folder import CLOUD, require_cloud, require_depth_maps
from mvsformerpp.io.ply import ply_colors, ply_points, read_ply, write_ply
from mvsformerpp.meshing.extract import Mesh, marching_cubes
from mvsformerpp.meshing.poisson import PoissonConfig, plan_poisson, screened_poisson
from mvsformerpp.meshing.tsdf import BYTES_PER_VOXEL, TSDFConfig, integrate, plan_grid, scene_box, surface_box
from mvsformerpp.utils.file_kinds import MESH
from mvsformerpp.utils.output_guard import claim_output_file


@dataclass(frozen=True)
class MeshConfig:
    """Settings of :func:`make_mesh`."""

    method: Literal["tsdf", "poisson"] = "tsdf"
    """tsdf: depth maps -> voxel grid -> marching cubes; poisson: fused oriented cloud -> screened Poisson."""
    tsdf: TSDFConfig = TSDFConfig()
    """TSDF settings (voxel size, truncation, confidence floor)."""
    poisson: PoissonConfig = PoissonConfig()
    """Poisson settings (octree depth, watertight, trimming)."""
    device: str = "cpu"
    """torch device of the TSDF integration (``cuda`` where there is one)."""


def make_mesh(folder: str | Path, out_ply: str | Path, config: MeshConfig = MeshConfig(), quiet: bool = False) -> Mesh:
    """Mesh the reconstruction in ``folder`` and write it to ``out_ply`` (binary PLY with vertex colours)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("no such output folder (make one with `mvsformerpp reconstruct INPUT -o OUT`)", folder)
    with claim_output_file(out_ply, MESH, [folder / CLOUD], run=folder):
        t0 = time.perf_counter()
        mesh = _tsdf_mesh(folder, config, quiet) if config.method == "tsdf" else _poisson_mesh(folder, config, quiet)
        if len(mesh.faces) == 0:
            raise InputError("the mesh came out empty: the depth maps agree nowhere; check them in report.html",
                             folder)
        write_ply(out_ply, mesh.vertices, mesh.colors, faces=mesh.faces, kind=MESH)
    if not quiet:
        print(f"{len(mesh.vertices):,} vertices, {len(mesh.faces):,} triangles ({config.method}) in "
              f"{time.perf_counter() - t0:.1f} s -> {out_ply}")
    return mesh


def _tsdf_mesh(folder: Path, config: MeshConfig, quiet: bool) -> Mesh:
    scene, depths, confs, images = load_depth_folder(require_depth_maps(folder))
    views = make_views(scene, depths, confs, images, config.device)
    box, where = scene_box(views), "the depth maps"
    cloud = folder / CLOUD
    if cloud.is_file():  # where the confident, consistent points lie: floaters and sky do not stretch it

        points = ply_points(read_ply(cloud), cloud)
        if len(points) >= 100:
            box, where = surface_box(points), "the fused cloud"
    budget = int(0.5 * resolution.available_memory_bytes(torch.device(config.device)) / BYTES_PER_VOXEL)
    tsdf = dataclasses.replace(config.tsdf, max_voxels=min(config.tsdf.max_voxels, budget))
    plan = plan_grid(views, tsdf, box)
    if not quiet:
        d = plan.dims
        print(f"TSDF: {d[0]}x{d[1]}x{d[2]} voxels of {plan.voxel:.4g} ({plan.note}), {plan.voxels / 1e6:.1f} M "
              f"voxels, about {plan.voxels * BYTES_PER_VOXEL / 2**30:.2f} GB; box from {where}", flush=True)
    with tqdm(total=len(views), desc="TSDF", unit="view", disable=quiet) as bar:
        volume = integrate(views, tsdf, progress=lambda: bar.update(1), plan=plan)
    if not quiet:
        print("TSDF: extracting the surface (marching cubes)", flush=True)
    return marching_cubes(volume)


def _poisson_mesh(folder: Path, config: MeshConfig, quiet: bool) -> Mesh:
    ply = require_cloud(folder)
    vertex = read_ply(ply)
    if not all(k in vertex for k in ("nx", "ny", "nz")):
        raise InputError("fused.ply has no normals (an older fusion); run `mvsformerpp fuse OUT` again to add "
                         "them", ply)
    xyz, normals = ply_points(vertex, ply), np.stack([vertex["nx"], vertex["ny"], vertex["nz"]], axis=1)
    plan = plan_poisson(xyz, normals, config.poisson)
    need, have = plan.memory_bytes, resolution.available_memory_bytes(torch.device("cpu"))
    if need > have:
        raise InputError(f"screened Poisson at --depth {config.poisson.depth} needs about {need / 2**30:.1f} GB "
                         f"({plan.points:,} points, {plan.occupied:,} occupied cells), more than the "
                         f"{have / 2**30:.1f} GB free; choose a smaller --depth (each level less needs about a "
                         "quarter of the cells)", ply)
    if not quiet:
        outside = len(xyz) - int(plan.inside.sum())
        thin = f", merged to one per {plan.thin:.4g} cube" if plan.thin is not None else ""
        print(f"Poisson: {plan.points:,} points of {len(xyz):,} ({outside:,} outside the surface's box or without "
              f"a normal{thin}), octree depth {config.poisson.depth} (cell {plan.cell:.4g}), about "
              f"{need / 2**30:.2f} GB", flush=True)
    t0 = time.perf_counter()
    mesh = screened_poisson(xyz, normals, ply_colors(vertex), config.poisson, plan=plan)
    if not quiet:
        print(f"Poisson: surface and trimming in {time.perf_counter() - t0:.1f} s", flush=True)
    return mesh
