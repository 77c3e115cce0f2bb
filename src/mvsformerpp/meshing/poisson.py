"""Screened Poisson surface reconstruction of an oriented point cloud (Kazhdan and Hoppe, TOG 2013).

Runs MeshLab's implementation through PyMeshLab (the ``mesh`` extra). The surface is closed by
construction except where it reaches the reconstruction box (an open scene, such as a ground plane,
stays open there); unless ``watertight`` is asked for, the parts that Poisson invents far from any sample
(vertices whose sample density is in the lowest ``trim`` percent) are cut away, as PoissonRecon's
SurfaceTrimmer does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.meshing.extract import Mesh


@dataclass(frozen=True)
class PoissonConfig:
    """Settings of :func:`screened_poisson`."""

    depth: int = 10
    """Octree depth: the surface has up to 2^depth cells along the scene box (10 ~ 1/1000 of its size)."""
    watertight: bool = False
    """Keep the closed surface as Poisson returns it (no trimming of low-density parts)."""
    trim: float = 10.0
    """Without ``watertight``: remove vertices whose sample density is in the lowest ``trim`` percent."""
    point_weight: float = 4.0
    """Screening weight: how strongly the surface is pulled through the points (0 = unscreened Poisson)."""
    threads: int = 1
    """Worker threads (MeshLab's OpenMP threads spin while waiting: on a busy machine more threads can be
    many times slower than one)."""


def _import_pymeshlab():
    try:
        import pymeshlab
    except ImportError as e:
        raise MissingDependencyError("pymeshlab", "mesh", "Poisson meshing") from e
    return pymeshlab


def screened_poisson(xyz: np.ndarray, normals: np.ndarray, colors: np.ndarray | None = None,
                     config: PoissonConfig = PoissonConfig()) -> Mesh:
    """Mesh an oriented cloud (points [N,3], unit normals [N,3], colours [N,3] uint8 or None)."""
    pymeshlab = _import_pymeshlab()
    ok = np.linalg.norm(normals, axis=1) > 0.5
    if ok.sum() < 100:
        raise InputError(f"only {int(ok.sum())} points have a normal; Poisson needs an oriented cloud (fuse the "
                         "depth maps again with `mvsformerpp fuse OUT` to get normals)")
    kwargs = {"vertex_matrix": xyz[ok].astype(np.float64), "v_normals_matrix": normals[ok].astype(np.float64)}
    if colors is not None:
        rgba = np.concatenate([colors[ok] / 255.0, np.ones((int(ok.sum()), 1))], axis=1)
        kwargs["v_color_matrix"] = rgba
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(**kwargs))
    ms.generate_surface_reconstruction_screened_poisson(depth=config.depth, pointweight=config.point_weight,
                                                         preclean=True, threads=config.threads)
    if not config.watertight and config.trim > 0:
        density = ms.current_mesh().vertex_scalar_array()
        cut = float(np.percentile(density, config.trim))
        ms.compute_selection_by_condition_per_vertex(condselect=f"q < {cut!r}")
        ms.meshing_remove_selected_vertices()
    m = ms.current_mesh()
    colors_out = None
    if colors is not None and m.has_vertex_color():
        colors_out = np.clip(np.round(m.vertex_color_matrix()[:, :3] * 255), 0, 255).astype(np.uint8)
    return Mesh(m.vertex_matrix().astype(np.float32), m.face_matrix().astype(np.int64), colors_out)
