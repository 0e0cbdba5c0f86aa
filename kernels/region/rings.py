"""Ring regions on the device: grow rings of neighbours from a contact vertex, then compact them.

The region's vertices live in one array, ring after ring: ring r occupies
``region_vertex[ring_offsets[r]:ring_offsets[r+1]]``. Growing ring r+1 launches one thread per
vertex of ring r (the compacted frontier) and appends the newly reached neighbours, so the work is
proportional to the region, not to the mesh. Ring membership is claimed with an integer
compare-and-swap, which gives the breadth-first ring index whatever the thread order; the order of
the new ring in the array is then made deterministic by a radix sort on vertex id.
"""

import warp as wp

from ..arrays import MeshArrays, RegionArrays

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.kernel
def seed_ring(seed: int, region: RegionArrays):
    # ring 0 is the contact vertex itself
    region.vertex_ring[seed] = 0
    region.region_vertex[0] = seed


@wp.kernel
def seed_rings(seeds: wp.array(dtype=wp.int32), region: RegionArrays):
    # ring 0 of a region of several probes: every probe's contact vertex (sorted, distinct: the host checks)
    i = wp.tid()
    region.vertex_ring[seeds[i]] = 0
    region.region_vertex[i] = seeds[i]


@wp.kernel
def grow_ring(mesh: MeshArrays, region: RegionArrays, frontier_begin: int, ring: int):
    # one thread per vertex of ring (ring - 1): claim each unvisited neighbour for `ring`
    v = region.region_vertex[frontier_begin + wp.tid()]
    for k in range(mesh.adj_offsets[v], mesh.adj_offsets[v + 1]):
        u = mesh.adj_vertex[k]
        if region.vertex_ring[u] < 0:
            if wp.atomic_cas(region.vertex_ring, u, -1, ring) == -1:
                slot = wp.atomic_add(region.region_count, 0, 1)
                region.region_vertex[slot] = u


@wp.func
def sort_ring(region_vertex: wp.array(dtype=wp.int32), begin: int, end: int):
    # insertion sort of region_vertex[begin:end] by vertex id (the radix sort's order), in one thread:
    # a ring's order must not depend on which thread claimed which vertex
    for i in range(begin + 1, end):
        key = region_vertex[i]
        j = i - 1
        while j >= begin and region_vertex[j] > key:
            region_vertex[j + 1] = region_vertex[j]
            j -= 1
        region_vertex[j + 1] = key


@wp.kernel
def sort_ring_small(region_vertex: wp.array(dtype=wp.int32), begin: int, count: int):
    # one thread sorts a short ring
    sort_ring(region_vertex, begin, begin + count)


@wp.kernel
def clear_region(region: RegionArrays):
    # forget the old region: only its own vertices are touched
    v = region.region_vertex[wp.tid()]
    region.vertex_ring[v] = -1
    region.vertex_local[v] = -1


@wp.kernel
def index_region(region: RegionArrays, outer_ring: int):
    # local index of each region vertex, its ring, and the boundary flag on the outermost ring
    i = wp.tid()
    v = region.region_vertex[i]
    r = region.vertex_ring[v]
    region.vertex_local[v] = i
    region.region_ring[i] = r
    region.region_boundary[i] = wp.where(r == outer_ring and outer_ring > 0, 1, 0)


@wp.kernel
def count_region_edges(mesh: MeshArrays, region: RegionArrays, edge_count: wp.array(dtype=wp.int32)):
    # each edge with both ends inside is owned by its lower-id end, so it is counted once
    v = region.region_vertex[wp.tid()]
    c = int(0)
    for k in range(mesh.adj_offsets[v], mesh.adj_offsets[v + 1]):
        u = mesh.adj_vertex[k]
        if u > v and region.vertex_ring[u] >= 0:
            c += 1
    edge_count[wp.tid()] = c


@wp.kernel
def write_region_edges(
    mesh: MeshArrays, region: RegionArrays, edge_count: wp.array(dtype=wp.int32), edge_end: wp.array(dtype=wp.int32)
):
    # the region's springs: mesh edge id and local end points, in owner order then CSR order
    i = wp.tid()
    v = region.region_vertex[i]
    slot = edge_end[i] - edge_count[i]
    for k in range(mesh.adj_offsets[v], mesh.adj_offsets[v + 1]):
        u = mesh.adj_vertex[k]
        if u > v and region.vertex_ring[u] >= 0:
            region.region_edge[slot] = mesh.adj_edge[k]
            region.region_edge_local[slot] = wp.vec2i(i, region.vertex_local[u])
            slot += 1


def seed_region_ring(region, seed):
    """Put `seed` alone on ring 0 of a cleared region."""
    wp.launch(seed_ring, dim=1, inputs=[seed, region.arrays], device=region.device)


def seed_region_rings(region, seeds):
    """Put the sorted, distinct `seeds` (device int32) on ring 0 of a cleared region."""
    wp.launch(seed_rings, dim=seeds.shape[0], inputs=[seeds, region.arrays], device=region.device)


def grow_region_ring(dmesh, region, frontier_begin, frontier_end, ring):
    """Append ring `ring` (the unvisited neighbours of region_vertex[frontier_begin:frontier_end])."""
    wp.launch(
        grow_ring, dim=frontier_end - frontier_begin, inputs=[dmesh.arrays, region.arrays, frontier_begin, ring], device=region.device
    )


def forget_region(region, count):
    """Mark the first `count` region vertices as outside again (vertex_ring and vertex_local -1)."""
    wp.launch(clear_region, dim=count, inputs=[region.arrays], device=region.device)


def index_region_vertices(region, count, outer_ring):
    """Local index, ring and boundary flag of the first `count` region vertices."""
    wp.launch(index_region, dim=count, inputs=[region.arrays, outer_ring], device=region.device)


SMALL_RING = 512
"""Rings up to this size are sorted by one thread; longer ones by Warp's radix sort."""


def sort_region_ring(region, begin, end):
    """Sort region_vertex[begin:end] by vertex id, so the region's order does not depend on threads."""
    count = end - begin
    if count < 2:
        return
    if count <= SMALL_RING:
        wp.launch(sort_ring_small, dim=1, inputs=[region.region_vertex, begin, count], device=region.device)
        return
    keys, values = region.sort_keys, region.sort_values
    wp.copy(keys, region.region_vertex, 0, begin, count)
    wp.utils.radix_sort_pairs(keys, values, count)
    wp.copy(region.region_vertex, keys, begin, 0, count)


def eval_region_edges(dmesh, region, count, edge_count, edge_end):
    """Count, scan and write the region's edges (each once, both ends inside).

    `edge_end` receives the inclusive scan of the counts: its entry count-1 is the total.
    """
    wp.launch(count_region_edges, dim=count, inputs=[dmesh.arrays, region.arrays, edge_count], device=region.device)
    wp.utils.array_scan(edge_count[:count], edge_end[:count], inclusive=True)
    wp.launch(write_region_edges, dim=count, inputs=[dmesh.arrays, region.arrays, edge_count, edge_end], device=region.device)
