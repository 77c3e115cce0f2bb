"""File formats: MVSNet cams/pair, PFM, COLMAP, Middlebury, dataset layouts, PLY; the Scene model."""

from mvsformerpp.io.images import image_size, read_image
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

__all__ = [
    "MVSNetCam",
    "Scene",
    "View",
    "image_size",
    "load_mvsnet_scene",
    "read_cam",
    "read_image",
    "read_pair",
    "read_pfm",
    "read_ply",
    "write_cam",
    "write_mvsnet_scene",
    "write_pair",
    "write_pfm",
    "write_ply",
]
