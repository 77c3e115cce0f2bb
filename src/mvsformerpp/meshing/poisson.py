"""Screened Poisson surface reconstruction of an oriented point cloud (Kazhdan and Hoppe, TOG 2013).

Runs MeshLab's implementation through PyMeshLab (the ``mesh`` extra). The surface is closed by
construction except where it reaches the reconstruction box (an open scene, such as a ground plane,
stays open there). Unless ``watertight`` is asked for, the parts that Poisson invents where no sample
lies are cut away: every vertex farther from the nearest sample than ``max_distance`` times the larger of
the cloud's sample spacing and the octree's cell (the bubbles that close an open scene behind its walls,
the skins spanned between floaters), then, as PoissonRecon's SurfaceTrimmer does, the lowest ``trim``
percent by sample density, and last the fragments these cuts leave (pieces of under ``min_fragment`` of
the triangles). A density percentile alone cannot do the first: on the demo's temple (depth 9) 13 % of
the closed surface lies over three cells from any sample, and a 10 % density cut leaves a third of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.geometry.voxels import count_voxels, voxel_means
from mvsformerpp.meshing.extract import Mesh
from mvsformerpp.meshing.tsdf import surface_box


@dataclass(frozen=True)
class PoissonConfig:
    """Settings of :func:`screened_poisson`."""

    depth: int = 10
    """Octree depth: the surface has up to 2^depth cells along the scene box (10 ~ 1/1000 of its size)."""
    watertight: bool = False
    """Keep the closed surface as Poisson returns it (no trimming of low-density parts)."""
    max_distance: float = 2.0
    """Without ``watertight``: remove vertices farther than this from every sample, in units of the larger of
    the median sample spacing and the octree cell (0 = no distance cut)."""
    trim: float = 0.0
    """Without ``watertight``: also remove vertices whose sample density is in the lowest ``trim`` percent."""
    min_fragment: float = 0.001
    """Without ``watertight``: drop connected pieces with fewer than this share of the triangles."""
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


BYTES_PER_POINT, BYTES_PER_CELL, BYTES_FIXED = 400, 3000, 100 * 2**20
"""MeshLab's screened Poisson's peak memory, fitted on a fused cloud (the demo's temple at depths 8-10, where it
is 7-15 % above the measured peak): a fixed part, per sample, and per octree cell at the finest depth that holds
a sample."""


@dataclass(frozen=True)
class PoissonPlan:
    """What :func:`screened_poisson` will mesh, known before it starts (see :func:`plan_poisson`)."""

    inside: np.ndarray
    """[N] bool: the oriented points inside the box of the confident surface (floaters far out are left out)."""
    cell: float
    """Octree cell at the finest depth, in scene units (MeshLab's box: the points' cube enlarged 1.1 times)."""
    thin: float | None
    """Points are merged to one per cube of this size (half a cell) when many share a cell, else None."""
    points: int
    """Samples Poisson receives."""
    occupied: int
    """Finest-depth cells holding a sample."""

    @property
    def memory_bytes(self) -> int:
        return BYTES_FIXED + BYTES_PER_POINT * self.points + BYTES_PER_CELL * self.occupied


def plan_poisson(xyz: np.ndarray, normals: np.ndarray, config: PoissonConfig = PoissonConfig()) -> PoissonPlan:
    """Which points go in, the cell, whether to thin them and the memory it needs."""

    oriented = np.linalg.norm(normals, axis=1) > 0.5
    if oriented.sum() < 100:
        raise InputError(f"only {int(oriented.sum())} points have a normal; Poisson needs an oriented cloud (fuse "
                         "the depth maps again with `mvsformerpp fuse OUT` to get normals)")
    lo, hi = surface_box(xyz[oriented])
    inside = oriented & (xyz >= lo).all(axis=1) & (xyz <= hi).all(axis=1)
    pts = xyz[inside].astype(np.float64)
    extent = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    if not extent > 0:
        raise InputError(f"the cloud's {len(pts):,} oriented points on its surface all lie at one place: there is no "
                         "surface for Poisson to fit; check the depth maps (report.html) or mesh with --method tsdf")
    cell = 1.1 * extent / 2**config.depth
    occupied = count_voxels(pts, cell)
    thin, n = None, len(pts)
    if n > 4 * occupied:  # far more samples than cells: their means at half a cell make the same surface
        thin = cell / 2
        n = count_voxels(pts, thin)
    return PoissonPlan(inside, cell, thin, n, occupied)


def screened_poisson(xyz: np.ndarray, normals: np.ndarray, colors: np.ndarray | None = None,
                     config: PoissonConfig = PoissonConfig(), plan: PoissonPlan | None = None) -> Mesh:
    """Mesh an oriented cloud (points [N,3], unit normals [N,3], colours [N,3] uint8 or None)."""
    pymeshlab = _import_pymeshlab()
    plan = plan or plan_poisson(xyz, normals, config)
    pts = xyz[plan.inside].astype(np.float64)
    nrm = normals[plan.inside].astype(np.float64)
    rgb = None if colors is None else colors[plan.inside].astype(np.float64) / 255.0
    if plan.thin is not None:
        values = nrm if rgb is None else np.concatenate([nrm, rgb], axis=1)
        pts, values = voxel_means(pts, plan.thin, values)
        nrm, rgb = values[:, :3], (None if rgb is None else values[:, 3:])
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        pts, nrm, rgb = (a[length[:, 0] > 1e-3] if a is not None else None for a in (pts, nrm, rgb))
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    kwargs = {"vertex_matrix": pts, "v_normals_matrix": nrm}
    if rgb is not None:
        kwargs["v_color_matrix"] = np.concatenate([rgb, np.ones((len(rgb), 1))], axis=1)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(**kwargs))
    ms.generate_surface_reconstruction_screened_poisson(depth=config.depth, pointweight=config.point_weight,
                                                         preclean=True, threads=config.threads)
    m = ms.current_mesh()
    colors_out = None
    if colors is not None and m.has_vertex_color():
        colors_out = np.clip(np.round(m.vertex_color_matrix()[:, :3] * 255), 0, 255).astype(np.uint8)
    mesh = Mesh(m.vertex_matrix().astype(np.float32), m.face_matrix().astype(np.int64), colors_out)
    if config.watertight:
        return mesh
    keep = np.ones(len(mesh.vertices), bool)
    if config.max_distance > 0:
        keep &= _near_samples(mesh.vertices, pts, plan.cell, config.max_distance)
    if config.trim > 0:
        density = m.vertex_scalar_array()
        keep &= density >= np.percentile(density, config.trim)
    trimmed = _drop_fragments(_keep_vertices(mesh, keep), config.min_fragment)
    if len(trimmed.faces) == 0 and len(mesh.faces) > 0:
        raise InputError(f"trimming removed every triangle of the Poisson surface (--trim {config.trim:g}, "
                         f"--max-distance {config.max_distance:g}); use a smaller --trim or --max-distance, or "
                         "--watertight to keep the closed surface")
    return trimmed


def _near_samples(vertices: np.ndarray, samples: np.ndarray, cell: float, max_distance: float) -> np.ndarray:
    """Which vertices lie within ``max_distance`` (sample spacing or octree cell, the larger) of a sample."""
    from scipy.spatial import cKDTree

    samples = samples.astype(np.float64)
    tree = cKDTree(samples)
    probe = samples[np.random.default_rng(0).choice(len(samples), min(len(samples), 20000), replace=False)]
    spacing = float(np.median(tree.query(probe, k=2)[0][:, 1]))
    reach = max_distance * max(spacing, cell)
    return tree.query(vertices.astype(np.float64), distance_upper_bound=reach)[0] <= reach


def _keep_vertices(mesh: Mesh, keep: np.ndarray) -> Mesh:
    """The mesh of the triangles whose three vertices are kept, vertices renumbered."""
    faces = mesh.faces[keep[mesh.faces].all(axis=1)]
    used = np.zeros(len(mesh.vertices), bool)
    used[faces.ravel()] = True
    index = np.cumsum(used) - 1
    return Mesh(mesh.vertices[used], index[faces].astype(np.int64),
                None if mesh.colors is None else mesh.colors[used])


def _drop_fragments(mesh: Mesh, min_share: float) -> Mesh:
    """Without the connected pieces that hold fewer than ``min_share`` of the triangles."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if min_share <= 0 or len(mesh.faces) == 0:
        return mesh
    n = len(mesh.vertices)
    edges = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    faces_per_piece = np.bincount(label[mesh.faces[:, 0]], minlength=label.max() + 1)
    big = faces_per_piece >= min_share * len(mesh.faces)
    return _keep_vertices(mesh, big[label])
