"""Ring regions for a batch of palpations, built on the device in one launch: B breadth-first searches.

Each palpation b gets compacted arrays of fixed capacity: its region's vertices in local order
(ring after ring, each ring sorted by vertex id: the order of ``Region``), the number of free
vertices (all but the fixed outermost non-empty ring) and, for each free vertex, its CSR
neighbours in mesh CSR order as local indices with their mesh edge ids (the step's topology,
built once per region). One thread per palpation: a region of a few hundred vertices at most,
so membership is a linear search of the region built so far, and no per-mesh-vertex array is
needed per palpation (memory stays proportional to B x region, not B x mesh).
"""

import warp as wp

from .rings import sort_ring

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

BUILD_OVERFLOW = 1
"""Status bit: the region has more vertices than the vertex capacity."""
BUILD_CSR_OVERFLOW = 2
"""Status bit: the free vertices have more CSR entries than the entry capacity."""


@wp.func
def find_local(region_vertex: wp.array2d(dtype=wp.int32), b: int, count: int, u: int):
    # local index of mesh vertex u in palpation b's region, -1 when not (yet) inside
    for i in range(count):
        if region_vertex[b, i] == u:
            return i
    return -1


@wp.kernel
def build_batch_regions(
    adj_offsets: wp.array(dtype=wp.int32),
    adj_vertex: wp.array(dtype=wp.int32),
    adj_edge: wp.array(dtype=wp.int32),
    seeds: wp.array(dtype=wp.int32),
    rings: int,
    region_vertex: wp.array2d(dtype=wp.int32),
    ring_offsets: wp.array2d(dtype=wp.int32),
    region_count: wp.array(dtype=wp.int32),
    free_count: wp.array(dtype=wp.int32),
    local_offsets: wp.array2d(dtype=wp.int32),
    local_neighbour: wp.array2d(dtype=wp.int32),
    local_edge: wp.array2d(dtype=wp.int32),
    local_owner: wp.array2d(dtype=wp.int32),
    local_spring: wp.array2d(dtype=wp.int32),
    spring_entry: wp.array2d(dtype=wp.int32),
    spring_count: wp.array(dtype=wp.int32),
    entry_count: wp.array(dtype=wp.int32),
    status: wp.array(dtype=wp.int32),
):
    b = wp.tid()
    capacity = region_vertex.shape[1]
    entry_capacity = local_neighbour.shape[1]
    seed = seeds[b]
    # ring 0 is the contact vertex itself
    region_vertex[b, 0] = seed
    ring_offsets[b, 0] = 0
    ring_offsets[b, 1] = 1
    count = int(1)
    begin = int(0)
    end = int(1)
    flags = int(0)
    outer = int(0)
    for r in range(1, rings + 1):
        # ring r: the neighbours of ring r - 1 not yet inside (breadth-first)
        for i in range(begin, end):
            v = region_vertex[b, i]
            for k in range(adj_offsets[v], adj_offsets[v + 1]):
                u = adj_vertex[k]
                if find_local(region_vertex, b, count, u) < 0:
                    if count < capacity:
                        region_vertex[b, count] = u
                        count += 1
                    else:
                        flags = flags | 1
        # sort the new ring by vertex id, as Region does
        sort_ring(region_vertex[b], end, count)
        ring_offsets[b, r + 1] = count
        if count > end:
            outer = r
        begin = end
        end = count
    # the outermost non-empty ring is fixed; everything inside it is free
    nf = count
    if outer > 0:
        nf = ring_offsets[b, outer]
    region_count[b] = count
    free_count[b] = nf
    # local topology of the free vertices: neighbours in mesh CSR order, as local indices
    slot = int(0)
    local_offsets[b, 0] = 0
    for i in range(nf):
        v = region_vertex[b, i]
        for k in range(adj_offsets[v], adj_offsets[v + 1]):
            if slot < entry_capacity:
                local_neighbour[b, slot] = find_local(region_vertex, b, count, adj_vertex[k])
                local_edge[b, slot] = adj_edge[k]
                local_owner[b, slot] = i
            else:
                flags = flags | 2
            slot += 1
        local_offsets[b, i + 1] = slot
    entry_count[b] = slot
    # each spring once: an entry i -> j is a spring's own when j is fixed or j > i; the entry
    # j -> i of two free ends reads it negated (its force is exactly the negation, bit for bit)
    springs = int(0)
    if flags == 0:
        for i in range(nf):
            for k in range(local_offsets[b, i], local_offsets[b, i + 1]):
                j = local_neighbour[b, k]
                if j >= nf or j > i:
                    spring_entry[b, springs] = k
                    local_spring[b, k] = springs + 1
                    springs += 1
                else:
                    for kk in range(local_offsets[b, j], local_offsets[b, j + 1]):
                        if local_neighbour[b, kk] == i:
                            local_spring[b, k] = -local_spring[b, kk]
    spring_count[b] = springs
    status[b] = flags


def build_regions(dmesh, seeds, rings, arrays):
    """Build every palpation's region around `seeds` (one launch; `arrays` holds the outputs)."""
    wp.launch(
        build_batch_regions,
        dim=len(seeds),
        inputs=[dmesh.adj_offsets, dmesh.adj_vertex, dmesh.adj_edge, seeds, rings],
        outputs=[
            arrays.region_vertex, arrays.ring_offsets, arrays.region_count, arrays.free_count,
            arrays.local_offsets, arrays.local_neighbour, arrays.local_edge, arrays.local_owner,
            arrays.local_spring, arrays.spring_entry, arrays.spring_count, arrays.entry_count, arrays.status,
        ],
        device=dmesh.device,
    )


@wp.kernel
def rest_batch_state(
    region_vertex: wp.array2d(dtype=wp.int32),
    region_count: wp.array(dtype=wp.int32),
    q_rest: wp.array(dtype=wp.vec3),
    q_state: wp.array2d(dtype=wp.vec3),
    qd_state: wp.array2d(dtype=wp.vec3),
    peak_force: wp.array(dtype=wp.float64),
    peak_reaction: wp.array(dtype=wp.vec3),
    hold_reaction: wp.array(dtype=wp.vec3),
):
    # every region vertex at rest, the probe's records cleared
    b = wp.tid()
    for i in range(region_count[b]):
        q_state[b, i] = q_rest[region_vertex[b, i]]
        qd_state[b, i] = wp.vec3(0.0)
    peak_force[b] = wp.float64(0.0)
    peak_reaction[b] = wp.vec3(0.0)
    hold_reaction[b] = wp.vec3(0.0)


def rest_states(batch):
    """Put every palpation's region at rest and clear its force records."""
    r = batch.regions
    wp.launch(
        rest_batch_state,
        dim=batch.batch_size,
        inputs=[r.region_vertex, r.region_count, batch.model.particle_q_rest],
        outputs=[batch.q_state, batch.qd_state, batch.peak_force, batch.peak_reaction, batch.hold_reaction],
        device=batch.device,
    )
