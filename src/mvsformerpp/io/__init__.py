"""File formats: MVSNet cams/pair, PFM, COLMAP, Middlebury, dataset layouts, PLY; the Scene model.

Entry point for user-given scenes: :func:`load_scene` (layout auto-detected by :func:`detect_layout`).
"""

from mvsformerpp.io.benchmarks import list_dtu_scans, load_blended_scene, load_dtu_scene, load_tnt_scene
from mvsformerpp.io.colmap import find_colmap_model, load_colmap_scene, undistort_colmap
from mvsformerpp.io.colmap_model import ColmapModel, read_model, write_model
from mvsformerpp.io.detect import LAYOUTS, detect_layout, load_scene
from mvsformerpp.io.images import image_size, read_image
from mvsformerpp.io.middlebury import load_middlebury_scene, read_par, write_par
from mvsformerpp.io.mvsnet import (
    MVSNetCam,
    load_mvsnet_scene,
    read_cam,
    read_pair,
    write_cam,
    write_mvsnet_scene,
    write_pair,
)
from mvsformerpp.io.pfm import read_pfm, write_pfm
from mvsformerpp.io.ply import read_ply, write_ply
from mvsformerpp.io.scene import Scene, View
from mvsformerpp.io.summary import summarize_scene

__all__ = [
    "LAYOUTS",
    "ColmapModel",
    "MVSNetCam",
    "Scene",
    "View",
    "detect_layout",
    "find_colmap_model",
    "image_size",
    "list_dtu_scans",
    "load_blended_scene",
    "load_colmap_scene",
    "load_dtu_scene",
    "load_middlebury_scene",
    "load_mvsnet_scene",
    "load_scene",
    "load_tnt_scene",
    "read_cam",
    "read_image",
    "read_model",
    "read_pair",
    "read_par",
    "read_pfm",
    "read_ply",
    "summarize_scene",
    "undistort_colmap",
    "write_cam",
    "write_model",
    "write_mvsnet_scene",
    "write_pair",
    "write_par",
    "write_pfm",
    "write_ply",
]
