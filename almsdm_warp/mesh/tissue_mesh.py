"""The tissue mesh: validated geometry on the host, with its topology computed once."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from . import topology as topo
from .validate import check_edge_lengths, repair_arrays


@dataclass(eq=False)
class TissueMesh:
    """A validated organ mesh, in SI units (metres).

    Build it with :func:`almsdm_warp.load_mesh` (which validates and repairs) or
    :meth:`from_arrays`; the arrays are not to be changed afterwards (the topology is cached).
    """

    vertices: np.ndarray
    """Rest positions [m], shape [vertex_count, 3], float64."""
    triangles: np.ndarray
    """The closed or open surface, wound outward, shape [triangle_count, 3], int32."""
    tetrahedra: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int32))
    """Tetrahedra, positively oriented, shape [tet_count, 4], int32; (0, 4) for a surface mesh."""
    path: str | None = None
    """The file it was read from, if any."""
    notes: tuple[str, ...] = ()
    """What validation found and repaired (dropped, merged, reoriented, reported), one line each."""

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32).reshape(-1, 3)
        self.tetrahedra = np.ascontiguousarray(self.tetrahedra, dtype=np.int32).reshape(-1, 4)
        self.notes = tuple(self.notes)

    # -- sizes -------------------------------------------------------------------------------
    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)

    @property
    def tet_count(self) -> int:
        return len(self.tetrahedra)

    @property
    def edge_count(self) -> int:
        return len(self.edges)

    @property
    def is_volume(self) -> bool:
        """True for a tetrahedral mesh (springs on tet edges), False for a surface mesh."""
        return self.tet_count > 0

    @property
    def vertices_mm(self) -> np.ndarray:
        """Rest positions in millimetres, shape [vertex_count, 3]."""
        return self.vertices * 1e3

    @property
    def name(self) -> str:
        import os

        return os.path.basename(self.path) if self.path else "<arrays>"

    # -- topology, computed once ---------------------------------------------------------------
    @cached_property
    def edges(self) -> np.ndarray:
        """Unique undirected edges (the springs), shape [edge_count, 2], int32, i < j, rows sorted."""
        return topo.unique_edges(self.triangles, self.tetrahedra)

    @cached_property
    def adjacency(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """CSR vertex adjacency (offsets [n+1], neighbour [2e], edge id [2e]), int32."""
        return topo.csr_adjacency(self.edges, self.vertex_count)

    @cached_property
    def vertex_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """CSR vertex-to-triangle incidence (offsets [n+1], triangle id), int32, for normals."""
        return topo.csr_incidence(self.triangles, self.vertex_count)

    @cached_property
    def edge_rest_length(self) -> np.ndarray:
        """Rest length of each edge [m], shape [edge_count], float64."""
        return topo.edge_lengths(self.vertices, self.edges)

    @cached_property
    def surface_vertices(self) -> np.ndarray:
        """Sorted ids of the vertices on the surface (all of them for a surface mesh), int32."""
        return topo.used_vertices(self.triangles, self.vertex_count).astype(np.int32)

    @cached_property
    def surface_tree(self):
        """A k-d tree (scipy's cKDTree) of the surface vertices' rest positions, built once: its
        point k is surface_vertices[k]."""
        from scipy.spatial import cKDTree

        return cKDTree(self.vertices[self.surface_vertices])

    def vertex_masses(self, density: float, thickness: float) -> np.ndarray:
        """Lumped vertex masses [kg], shape [vertex_count].

        density [kg/m^3]; thickness [m] (surface meshes only: area x thickness x density).
        """
        return topo.lumped_masses(self.vertices, self.triangles, self.tetrahedra, density, thickness)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_arrays(cls, vertices, triangles=None, tetrahedra=None, *, scale: float = 1.0, path=None):
        """Validate and repair raw arrays (coordinates in mm x `scale`) into a mesh, as load_mesh does."""
        fields, keep, where = repair_arrays(vertices, triangles, tetrahedra, scale=scale, path=path)
        mesh = cls(**fields)
        check_edge_lengths(mesh, keep, where)
        return mesh

    def summary(self) -> str:
        kind = f"{self.tet_count} tets, " if self.is_volume else ""
        return (
            f"{self.name}: {self.vertex_count} vertices, {self.triangle_count} surface triangles, "
            f"{kind}{self.edge_count} edges"
        )
