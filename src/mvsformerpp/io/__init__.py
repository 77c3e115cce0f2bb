"""File formats: MVSNet cams/pair, PFM, COLMAP, Middlebury, dataset layouts, PLY; the Scene model."""

from mvsformerpp.io.pfm import read_pfm, write_pfm
from mvsformerpp.io.ply import read_ply, write_ply
from mvsformerpp.io.scene import Scene, View

__all__ = ["Scene", "View", "read_pfm", "write_pfm", "read_ply", "write_ply"]
