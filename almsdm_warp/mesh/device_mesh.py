"""A tissue mesh's topology and rest geometry on one Warp device, uploaded once."""

from __future__ import annotations

import weakref

import numpy as np
import warp as wp

from ..kernels.arrays import MeshArrays, struct_from
from .tissue_mesh import TissueMesh

_cache: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class DeviceMesh:
    """The static arrays that the contact, ring and step kernels read, on one device.

    Float32 on the device (positions in metres); the host mesh keeps float64.
    """

    def __init__(self, mesh: TissueMesh, device=None):
        self.mesh = mesh
        self.device = wp.get_device(device)
        d = self.device
        self.vertex_count = mesh.vertex_count
        self.edge_count = mesh.edge_count
        offsets, neighbours, edge_ids = mesh.adjacency
        self.adj_offsets = wp.array(offsets, dtype=wp.int32, device=d)
        """CSR offsets of the vertex adjacency, shape [vertex_count + 1], int32."""
        self.adj_vertex = wp.array(neighbours, dtype=wp.int32, device=d)
        """CSR neighbour ids, shape [2 * edge_count], int32."""
        self.adj_edge = wp.array(edge_ids, dtype=wp.int32, device=d)
        """Edge id of each CSR entry, shape [2 * edge_count], int32."""
        self.edges = wp.array(mesh.edges, dtype=wp.int32, device=d)
        """Unique edges (i < j), shape [edge_count, 2], int32."""
        self.edge_rest_length = wp.array(mesh.edge_rest_length, dtype=wp.float32, device=d)
        """Rest length of each edge [m], shape [edge_count], float32."""
        self.rest_position = wp.array(mesh.vertices, dtype=wp.vec3, device=d)
        """Rest positions [m], shape [vertex_count], vec3."""
        self.triangles = wp.array(mesh.triangles, dtype=wp.int32, device=d)
        """Surface triangles, shape [triangle_count, 3], int32."""
        face_offsets, face_ids = mesh.vertex_faces
        self.vertex_face_offsets = wp.array(face_offsets, dtype=wp.int32, device=d)
        """CSR offsets of the vertex-to-triangle incidence, shape [vertex_count + 1], int32."""
        self.vertex_face = wp.array(face_ids, dtype=wp.int32, device=d)
        """Triangle ids around each vertex, shape [3 * triangle_count], int32."""
        # contact: the surface's BVH, and a BVH over the surface vertices (points as boxes)
        self.surface = wp.Mesh(points=self.rest_position, indices=self.triangles.flatten())
        surface_vertices = mesh.surface_vertices
        self.bvh_vertex = wp.array(surface_vertices, dtype=wp.int32, device=d)
        """Vertex id of each item of `vertex_bvh`, shape [surface vertex count], int32."""
        pts = wp.array(mesh.vertices[surface_vertices], dtype=wp.vec3, device=d)
        self._bvh_points = pts  # the BVH keeps pointers to its bounds
        self.vertex_bvh = wp.Bvh(pts, pts)
        self.arrays = struct_from(MeshArrays, self)
        """The topology above as one struct, the argument of the ring, contact and normals kernels."""

    @classmethod
    def of(cls, mesh: TissueMesh, device=None) -> "DeviceMesh":
        """The mesh's arrays on `device`, uploaded once and shared while the mesh lives."""
        device = wp.get_device(device)
        per_mesh = _cache.setdefault(mesh, {})
        dm = per_mesh.get(device.alias)
        if dm is None:
            dm = per_mesh[device.alias] = cls(mesh, device)
        return dm


def as_device_mesh(mesh, device=None) -> DeviceMesh:
    """Accept a TissueMesh or a DeviceMesh; return the DeviceMesh on `device`."""
    if isinstance(mesh, DeviceMesh):
        if device is not None and wp.get_device(device) != mesh.device:
            return DeviceMesh.of(mesh.mesh, device)
        return mesh
    if not isinstance(mesh, TissueMesh):
        raise TypeError(f"expected a TissueMesh or DeviceMesh, got {type(mesh).__name__}")
    return DeviceMesh.of(mesh, device)


def check_vertex(mesh: TissueMesh, vertex, what: str = "seed vertex") -> int:
    """An int vertex id inside the mesh, or a ValueError that gives the valid range."""
    if isinstance(vertex, (bool, np.bool_)) or not isinstance(vertex, (int, np.integer)):
        raise TypeError(f"{what} must be an int, got {type(vertex).__name__}")
    v = int(vertex)
    n = mesh.vertex_count
    if not 0 <= v < n:
        raise ValueError(f"{what} {v} is outside the mesh, which has {n} vertices (0..{n - 1})")
    return v
