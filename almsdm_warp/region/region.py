"""The local region of the ALMSDM: rings of neighbours around a contact vertex, on the device."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..mesh.device_mesh import as_device_mesh, check_vertex
from ..kernels.region import rings as rk
from ..kernels.arrays import RegionArrays, struct_from
from ..checks import rings_text


def check_rings(rings) -> int:
    if isinstance(rings, (bool, np.bool_)) or not isinstance(rings, (int, np.integer)):
        raise TypeError(f"rings must be an int, got {type(rings).__name__}")
    if rings < 0:
        raise ValueError(f"rings must be >= 0, got {rings}")
    return int(rings)


def check_vertices(mesh, vertices) -> np.ndarray:
    """Vertex ids (any integer sequence) as int32, or check_vertex's error for the first one outside the mesh."""
    ids = np.asarray(vertices).reshape(-1)
    if ids.size and not np.issubdtype(ids.dtype, np.integer):
        return np.asarray([check_vertex(mesh, int(v)) for v in ids.tolist()], dtype=np.int32)
    bad = np.flatnonzero((ids < 0) | (ids >= mesh.vertex_count))
    if len(bad):
        check_vertex(mesh, int(ids[bad[0]]))
    return ids.astype(np.int32)


class Region:
    """A ring region on one device: its vertices, springs, local indices and fixed outer ring.

    Arrays are sized for the whole mesh once; building, relocating and expanding touch only the
    region's own vertices. Region vertices are stored ring after ring, each ring sorted by vertex
    id, so local indices are deterministic, and expanding appends: the local indices of the
    vertices already inside do not change.
    """

    def __init__(self, mesh, device=None):
        self.dmesh = dm = as_device_mesh(mesh, device)
        self.device = dm.device
        n, e = dm.vertex_count, dm.edge_count
        d = self.device
        self.vertex_ring = wp.full(n, -1, dtype=wp.int32, device=d)
        """Ring index of every mesh vertex, -1 outside the region, shape [vertex_count], int32."""
        self.vertex_local = wp.full(n, -1, dtype=wp.int32, device=d)
        """Local index of every mesh vertex, -1 outside, shape [vertex_count], int32."""
        self.region_vertex = wp.zeros(n, dtype=wp.int32, device=d)
        """Mesh id of each region vertex in local order; the first `vertex_count` are valid."""
        self.region_ring = wp.zeros(n, dtype=wp.int32, device=d)
        """Ring index of each region vertex, local order, int32."""
        self.region_boundary = wp.zeros(n, dtype=wp.int32, device=d)
        """1 on the outermost ring (fixed), else 0, local order, int32."""
        self.region_edge = wp.zeros(max(e, 1), dtype=wp.int32, device=d)
        """Mesh edge id of each region spring; the first `spring_count` are valid."""
        self.region_edge_local = wp.zeros(max(e, 1), dtype=wp.vec2i, device=d)
        """Local end points (i, j) of each region spring."""
        self.region_count = wp.zeros(1, dtype=wp.int32, device=d)
        # the ring growth reads the counter after each ring: a view kept on the CPU (no wrapper a read)
        self._count_view = self.region_count.numpy() if self.device.is_cpu else None
        self.arrays = struct_from(RegionArrays, self)
        """The arrays above as one struct, the argument of the ring kernels (allocated once, never replaced)."""
        # scratch: per-vertex edge counts and their scan; sort buffers (radix sort needs 2x)
        self._edge_count = wp.zeros(n, dtype=wp.int32, device=d)
        self._edge_end = wp.zeros(n, dtype=wp.int32, device=d)
        self.sort_keys = wp.zeros(2 * n, dtype=wp.int32, device=d)
        self.sort_values = wp.zeros(2 * n, dtype=wp.int32, device=d)
        self.seed = -1
        self.rings = 0
        """Rings asked for (the outermost may be empty when the region covers its component)."""
        self.ring_offsets = np.zeros(1, dtype=np.int64)
        """Host: ring r is region_vertex[ring_offsets[r]:ring_offsets[r+1]]. Growth stops at the
        first empty ring (the region covers its component): rings past len(ring_offsets) - 1, up to
        `rings`, are empty and not recorded."""
        self.spring_count = 0

    # -- size ----------------------------------------------------------------------------------
    @property
    def vertex_count(self) -> int:
        """Region vertices, the fixed outer ring included."""
        return int(self.ring_offsets[-1])

    @property
    def outer_ring(self) -> int:
        """The last non-empty ring: the one that is fixed (0 when the region is just the seed)."""
        sizes = np.diff(self.ring_offsets)
        nonempty = np.flatnonzero(sizes)
        return int(nonempty[-1]) if len(nonempty) else 0

    @property
    def boundary_count(self) -> int:
        r = self.outer_ring
        return int(self.ring_offsets[r + 1] - self.ring_offsets[r]) if r > 0 else 0

    @property
    def free_count(self) -> int:
        return self.vertex_count - self.boundary_count

    @property
    def is_empty(self) -> bool:
        return self.seed < 0

    # -- building ------------------------------------------------------------------------------
    def build(self, seed_vertex: int, rings: int) -> "Region":
        """Build the region of `rings` rings around `seed_vertex`, clearing any old region first."""
        seed = check_vertex(self.dmesh.mesh, seed_vertex)
        rings = check_rings(rings)
        self.clear()
        rk.seed_region_ring(self, seed)
        self.region_count.fill_(1)
        self.seed = seed
        self.rings = 0
        self.ring_offsets = np.array([0, 1], dtype=np.int64)
        self._grow(rings)
        return self

    def build_seeds(self, seeds, rings: int, contact: int | None = None, *, index: bool = True) -> "Region":
        """Build the region of `rings` rings around several seed vertices (ring 0: all of them; ring r:
        the vertices r hops from the nearest), clearing any old region first. `contact`: the vertex
        the region is read at (`seed`; default the smallest seed), e.g. a spherical probe's contact
        in the middle of its patch. index=False leaves the local indices, the fixed ring and the springs
        to the expand() that must follow (a build spread over steps computes them once)."""
        seeds = np.unique(check_vertices(self.dmesh.mesh, seeds))
        if len(seeds) == 0:
            raise ValueError("a region needs at least one seed vertex")
        rings = check_rings(rings)
        seed = int(seeds[0]) if contact is None else check_vertex(self.dmesh.mesh, contact)
        if seed not in seeds:
            raise ValueError(f"the contact vertex {seed} is not one of the region's seeds")
        self.clear()
        rk.seed_region_rings(self, wp.array(seeds, dtype=wp.int32, device=self.device))
        self.region_count.fill_(len(seeds))
        self.seed = seed
        self.seeds = seeds
        self.rings = 0
        self.ring_offsets = np.array([0, len(seeds)], dtype=np.int64)
        self._grow(rings, index)
        return self

    def expand(self, rings: int = 1) -> "Region":
        """Grow the region by `rings` more rings in place; vertices inside keep their local index."""
        if self.is_empty:
            raise RuntimeError("expand() needs a region: call build() first")
        self._grow(check_rings(rings))
        return self

    def clear(self) -> None:
        """Remove the region: its vertices are forgotten, its springs and boundary gone."""
        count = self.vertex_count
        if count:
            rk.forget_region(self, count)
        self.seed = -1
        self.rings = 0
        self.ring_offsets = np.zeros(1, dtype=np.int64)
        self.spring_count = 0

    def _grow(self, rings: int, index: bool = True) -> None:
        dm = self.dmesh
        offsets = list(self.ring_offsets)
        for done in range(rings):
            begin, end = int(offsets[-2]), int(offsets[-1])
            if end == begin:
                # the region already covers its component: the remaining rings are empty, and are
                # counted in `rings` but not recorded (10**20 of them would not fit in memory)
                self.rings += rings - done
                break
            self.rings += 1
            rk.grow_region_ring(dm, self, begin, end, self.rings)
            new_end = int(self._count_view[0] if self._count_view is not None else self.region_count.numpy()[0])
            rk.sort_region_ring(self, end, new_end)
            offsets.append(new_end)
        self.ring_offsets = np.asarray(offsets, dtype=np.int64)
        if index:
            self._compact()

    def _compact(self) -> None:
        # local indices, ring and boundary flags, then the springs (each edge once)
        dm = self.dmesh
        count = self.vertex_count
        rk.index_region_vertices(self, count, self.outer_ring)
        rk.eval_region_edges(dm, self, count, self._edge_count, self._edge_end)
        self.spring_count = int(self._edge_end[count - 1 : count].numpy()[0])

    # -- reading back --------------------------------------------------------------------------
    def vertices(self) -> np.ndarray:
        """Mesh ids of the region's vertices in local order (host copy), int32."""
        return self.region_vertex.numpy()[: self.vertex_count].copy()

    def springs(self) -> np.ndarray:
        """Mesh edge ids of the region's springs (host copy), int32."""
        return self.region_edge.numpy()[: self.spring_count].copy()

    def boundary(self) -> np.ndarray:
        """Mesh ids of the fixed outer-ring vertices (host copy), int32."""
        flags = self.region_boundary.numpy()[: self.vertex_count].astype(bool)
        return self.vertices()[flags]

    def summary(self) -> str:
        sizes = np.diff(self.ring_offsets).tolist()
        return (
            f"region at vertex {self.seed}: {rings_text(self.rings)}, {self.vertex_count} vertices "
            f"(per ring {sizes}), {self.spring_count} springs, {self.boundary_count} fixed on ring {self.outer_ring}"
        )


def ring_distances(mesh, seed_vertex: int, rings: int, *, device=None) -> np.ndarray:
    """Ring index of every vertex around `seed_vertex` (breadth-first hops along mesh edges).

    Returns a NumPy int32 array of shape [vertex_count]: 0 at the seed, r on ring r, -1 beyond
    `rings` or unreachable. Built on `device` (default: Warp's default device) by the region kernels.
    """
    region = Region(mesh, device).build(seed_vertex, rings)
    return region.vertex_ring.numpy().copy()
