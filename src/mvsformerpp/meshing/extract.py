"""Triangle mesh of a TSDF grid's zero level set (scikit-image's marching cubes, Lewiner et al. 2003).

Only cubes whose eight corners were all observed take part: the jump between observed space behind a
surface and never-observed space is not a surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch.nn.functional as F

from mvsformerpp.errors import InputError, MissingDependencyError
from mvsformerpp.meshing.tsdf import TSDFVolume


@dataclass
class Mesh:
    """Vertices [N,3] float32 (scene units), triangles [M,3] int64, vertex colours [N,3] uint8 or None."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None


def marching_cubes(volume: TSDFVolume, min_weight: float = 0.0) -> Mesh:
    """The zero crossing of ``volume.tsdf`` among voxels with weight above ``min_weight``."""
    try:
        from skimage.measure import marching_cubes as skimage_marching_cubes
    except ImportError as e:
        raise MissingDependencyError("scikit-image", "mesh", "TSDF meshing") from e
    observed = volume.weight > min_weight
    # a cube (i, j, k) .. (i+1, j+1, k+1) is usable when all its corners are observed
    cube_ok = -F.max_pool3d(-observed[None, None].float(), kernel_size=2, stride=1)[0, 0] > 0.5
    if not cube_ok.any():
        raise InputError("the depth maps observed no part of the grid twice over: nothing to mesh")
    tsdf = volume.tsdf.cpu().numpy()
    if not (tsdf[observed.cpu().numpy()] < 0).any():
        raise InputError("the TSDF has no surface (no voxel behind a depth): check the depth maps")
    verts, faces, _, _ = skimage_marching_cubes(tsdf, level=0.0, mask=observed.cpu().numpy(),
                                                allow_degenerate=False)
    cell = np.clip(np.floor(verts).astype(np.int64), 0, np.array(cube_ok.shape) - 1)
    good_vert = cube_ok.cpu().numpy()[cell[:, 0], cell[:, 1], cell[:, 2]]
    faces = faces[good_vert[faces].all(1)]
    used = np.unique(faces)
    remap = np.full(len(verts), -1, np.int64)
    remap[used] = np.arange(len(used))
    verts, faces = verts[used], remap[faces]
    color = volume.color.cpu().numpy()
    idx = np.clip(np.round(verts).astype(np.int64), 0, np.array(tsdf.shape) - 1)
    colors = np.clip(np.round(color[idx[:, 0], idx[:, 1], idx[:, 2]]), 0, 255).astype(np.uint8)
    # grid index -> world: voxel centres sit at origin + (index + 0.5) * voxel
    world = (volume.origin + (verts + 0.5) * volume.voxel).astype(np.float32)
    return Mesh(world, faces.astype(np.int64), colors)
