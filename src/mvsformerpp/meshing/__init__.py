"""Meshes from a reconstruction: TSDF integration + marching cubes, or screened Poisson on the fused cloud.

The heavy parts come from libraries of the field: scikit-image's marching cubes and MeshLab's screened
Poisson (PyMeshLab), both in the ``mesh`` extra.
"""

from mvsformerpp.meshing.tsdf import TSDFConfig, TSDFVolume, integrate

__all__ = ["TSDFConfig", "TSDFVolume", "integrate"]
