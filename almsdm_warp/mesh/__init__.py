"""Mesh loading and validation: files in, a validated TissueMesh (host) and its DeviceMesh out."""

from .device_mesh import DeviceMesh
from .io import load_mesh
from .tissue_mesh import TissueMesh

__all__ = ["DeviceMesh", "TissueMesh", "load_mesh"]
