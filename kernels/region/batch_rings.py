"""Ring regions for a batch of palpations, built on the device in one launch: B breadth-first searches.

Each palpation b gets compacted arrays of fixed capacity: its region's vertices in local order
(ring after ring from its seeds, each ring sorted by vertex id: the order of ``Region.build`` and
``Region.build_seeds``), the number of free vertices (all but the fixed outermost non-empty ring,
less the supported vertices, which are moved to just after the free ones) and, for each free vertex, its CSR
neighbours in mesh CSR order as local indices with their mesh edge ids (the step's topology,
built once per region). One thread per palpation; membership is a binary search of each ring built
so far (each sorted by vertex id) and a linear one of the ring being built (find_local), so that no
per-mesh-vertex array is needed per palpation (memory stays proportional to B x region, not B x mesh).
Once built, a region whose support moved vertices out of ring order is searched in its sorted runs
(sorted_runs, find_in_runs: at most twice its rings and one), never linearly: the liver scene's 6-ring regions,
nearly all of which reach its support, build their tets 4x sooner (docs/performance.md).
"""

import warp as wp

from ..arrays import BatchPress, BatchRegionArrays, MeshArrays, TissueArrays
from .rings import sort_ring

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

BUILD_OVERFLOW = 1
"""Status bit: the region has more vertices than the vertex capacity."""
BUILD_CSR_OVERFLOW = 2
"""Status bit: the free vertices have more CSR entries than the entry capacity."""


@wp.func
def search_sorted(region_vertex: wp.array2d(dtype=wp.int32), b: int, begin: int, end: int, u: int):
    # the index of mesh vertex u in palpation b's region_vertex[b, begin:end] (sorted by vertex id), else -1
    lo = begin
    hi = end
    while lo < hi:
        mid = lo + (hi - lo) // 2
        w = region_vertex[b, mid]
        if w < u:
            lo = mid + 1
        elif w > u:
            hi = mid
        else:
            return mid
    return -1


@wp.func
def find_local(region_vertex: wp.array2d(dtype=wp.int32), ring_offsets: wp.array2d(dtype=wp.int32), b: int, sorted_rings: int,
               count: int, u: int):
    # local index of mesh vertex u in palpation b's region, -1 when not (yet) inside: a binary search of
    # each of its first `sorted_rings` rings (sorted by vertex id: ring_offsets[b, r]..ring_offsets[b, r + 1]),
    # then a linear one of the rest, up to `count` (0 sorted rings: all of it). The same index as a linear
    # search of the whole (each vertex is in the region once), in log time for a large region's rings:
    # a fine mesh under a sphere has regions of thousands of vertices (0.27 mm edges: 16 of ~10,000 took 23 s)
    for r in range(sorted_rings):
        i = search_sorted(region_vertex, b, ring_offsets[b, r], ring_offsets[b, r + 1], u)
        if i >= 0:
            return i
    for i in range(ring_offsets[b, sorted_rings], count):
        if region_vertex[b, i] == u:
            return i
    return -1


@wp.func
def rings_sorted(region_vertex: wp.array2d(dtype=wp.int32), ring_offsets: wp.array2d(dtype=wp.int32), b: int):
    # the number of palpation b's rings (all of them) when each is sorted by vertex id, as its growth leaves
    # them; 0 where a support moved vertices out of order (hold_supports): the built region's lookups then
    # binary-search its sorted runs (find_built)
    rings = ring_offsets.shape[1] - 1
    for r in range(rings):
        for i in range(ring_offsets[b, r] + 1, ring_offsets[b, r + 1]):
            if region_vertex[b, i - 1] > region_vertex[b, i]:
                return 0
    return rings


SEARCH_RUNS = 64
"""A region's sorted runs that `find_in_runs` binary-searches at most (more: a linear search)."""
RunEnds = wp.types.vector(length=SEARCH_RUNS + 1, dtype=wp.int32)


@wp.func
def sorted_runs(region_vertex: wp.array2d(dtype=wp.int32), b: int, count: int):
    # palpation b's region cut into its maximal runs of increasing vertex id: (ends, runs), run r is
    # region_vertex[b, ends[r]:ends[r + 1]]; runs 0 where there are more than SEARCH_RUNS. Where a support
    # moved vertices out of ring order (hold_supports), the free vertices left in the set and those it
    # moved after them are each still in ring order, so a region has at most twice its rings' runs
    ends = RunEnds()
    runs = int(0)
    for i in range(1, count):
        if region_vertex[b, i - 1] > region_vertex[b, i]:
            runs += 1
            if runs < SEARCH_RUNS:
                ends[runs] = i
    runs += 1
    if runs > SEARCH_RUNS:
        return ends, 0
    ends[runs] = count
    return ends, runs


@wp.func
def find_in_runs(region_vertex: wp.array2d(dtype=wp.int32), b: int, ends: RunEnds, runs: int, count: int, u: int):
    # local index of mesh vertex u in palpation b's built region, -1 when not inside: a binary search of
    # each of its sorted runs (sorted_runs), or with none given (runs 0) a linear search of all `count`
    for r in range(runs):
        i = search_sorted(region_vertex, b, ends[r], ends[r + 1], u)
        if i >= 0:
            return i
    if runs == 0:
        for i in range(count):
            if region_vertex[b, i] == u:
                return i
    return -1


@wp.func
def find_built(region_vertex: wp.array2d(dtype=wp.int32), ring_offsets: wp.array2d(dtype=wp.int32), b: int, sorted_rings: int,
               ends: RunEnds, runs: int, count: int, u: int):
    # local index of mesh vertex u in palpation b's built region (-1: outside): its rings' binary searches
    # where each ring is sorted (sorted_rings > 0), else those of its sorted runs
    if sorted_rings > 0:
        return find_local(region_vertex, ring_offsets, b, sorted_rings, count, u)
    return find_in_runs(region_vertex, b, ends, runs, count, u)


@wp.func
def hold_supports(region_vertex: wp.array2d(dtype=wp.int32), b: int, nf: int, support: wp.array(dtype=wp.int32)):
    # the supported vertices leave the free set: moved, in order, to just after the free ones (the
    # others keep their order, as SolverBase.without_supports does); returns the free count
    w = int(0)
    for i in range(nf):
        v = region_vertex[b, i]
        if support[v] == 0:
            # rotate [w, i] right by one: v to w, the held vertices between keep their order
            for k in range(i, w, -1):
                region_vertex[b, k] = region_vertex[b, k - 1]
            region_vertex[b, w] = v
            w += 1
    return w


@wp.kernel
def build_batch_regions(
    mesh: MeshArrays,
    seed_offsets: wp.array(dtype=wp.int32),
    seeds: wp.array(dtype=wp.int32),
    rings: int,
    support: wp.array(dtype=wp.int32),
    regions: BatchRegionArrays,
):
    b = wp.tid()
    capacity = regions.region_vertex.shape[1]
    entry_capacity = regions.local_neighbour.shape[1]
    # ring 0: the palpation's seeds (the contact vertex, or a sphere's patch), sorted by vertex id
    count = int(0)
    flags = int(0)
    for k in range(seed_offsets[b], seed_offsets[b + 1]):
        if count < capacity:
            regions.region_vertex[b, count] = seeds[k]
            count += 1
        else:
            flags = flags | 1
    regions.ring_offsets[b, 0] = 0
    regions.ring_offsets[b, 1] = count
    grown = int(1)  # the rings find_local may binary-search while the next grows: the seeds' and every grown one (sorted)
    for i in range(1, count):
        if regions.region_vertex[b, i - 1] >= regions.region_vertex[b, i]:
            grown = 0  # seeds out of order (none of this module's callers): linear searches, as before
    begin = int(0)
    end = count
    outer = int(0)
    for r in range(1, rings + 1):
        # ring r: the neighbours of ring r - 1 not yet inside (breadth-first)
        for i in range(begin, end):
            v = regions.region_vertex[b, i]
            for k in range(mesh.adj_offsets[v], mesh.adj_offsets[v + 1]):
                u = mesh.adj_vertex[k]
                if find_local(regions.region_vertex, regions.ring_offsets, b, grown * r, count, u) < 0:  # rings 0..r-1 sorted
                    if count < capacity:
                        regions.region_vertex[b, count] = u
                        count += 1
                    else:
                        flags = flags | 1
        # sort the new ring by vertex id, as Region does
        sort_ring(regions.region_vertex[b], end, count)
        regions.ring_offsets[b, r + 1] = count
        if count > end:
            outer = r
        begin = end
        end = count
    # the outermost non-empty ring is fixed; everything inside it is free
    nf = count
    if outer > 0:
        nf = regions.ring_offsets[b, outer]
    if support.shape[0] > 1:
        nf = hold_supports(regions.region_vertex, b, nf, support)
    regions.region_count[b] = count
    regions.free_count[b] = nf
    # local topology of the free vertices: neighbours in mesh CSR order, as local indices
    sorted_rings = rings_sorted(regions.region_vertex, regions.ring_offsets, b)
    ends, runs = sorted_runs(regions.region_vertex, b, count)
    slot = int(0)
    regions.local_offsets[b, 0] = 0
    for i in range(nf):
        v = regions.region_vertex[b, i]
        for k in range(mesh.adj_offsets[v], mesh.adj_offsets[v + 1]):
            if slot < entry_capacity:
                regions.local_neighbour[b, slot] = find_built(regions.region_vertex, regions.ring_offsets, b, sorted_rings, ends, runs, count,
                                                              mesh.adj_vertex[k])
                regions.local_edge[b, slot] = mesh.adj_edge[k]
                regions.local_owner[b, slot] = i
            else:
                flags = flags | 2
            slot += 1
        regions.local_offsets[b, i + 1] = slot
    regions.entry_count[b] = slot
    # each spring once: an entry i -> j is a spring's own when j is fixed or j > i; the entry
    # j -> i of two free ends reads it negated (its force is exactly the negation, bit for bit)
    springs = int(0)
    if flags == 0:
        for i in range(nf):
            for k in range(regions.local_offsets[b, i], regions.local_offsets[b, i + 1]):
                j = regions.local_neighbour[b, k]
                if j >= nf or j > i:
                    regions.spring_entry[b, springs] = k
                    regions.local_spring[b, k] = springs + 1
                    springs += 1
                else:
                    for kk in range(regions.local_offsets[b, j], regions.local_offsets[b, j + 1]):
                        if regions.local_neighbour[b, kk] == i:
                            regions.local_spring[b, k] = -regions.local_spring[b, kk]
    regions.spring_count[b] = springs
    regions.status[b] = flags


@wp.func
def corner_local(region_vertex: wp.array2d(dtype=wp.int32), ring_offsets: wp.array2d(dtype=wp.int32), b: int, sorted_rings: int,
                 ends: RunEnds, runs: int, count: int, u: int):
    # a tet corner's local index in palpation b's region, or -(u + 1) for a mesh vertex outside it
    i = find_built(region_vertex, ring_offsets, b, sorted_rings, ends, runs, count, u)
    if i < 0:
        return -(u + 1)
    return i


@wp.kernel
def batch_region_runs(region_vertex: wp.array2d(dtype=wp.int32), ring_offsets: wp.array2d(dtype=wp.int32),
                      region_count: wp.array(dtype=wp.int32), sorted_rings: wp.array(dtype=wp.int32), run_ends: wp.array(dtype=RunEnds),
                      runs: wp.array(dtype=wp.int32)):
    # how palpation b's built region is searched (find_built): its sorted rings (rings_sorted), else its
    # sorted runs (sorted_runs), found once for every lookup of build_batch_elements' threads
    b = wp.tid()
    rings = rings_sorted(region_vertex, ring_offsets, b)
    sorted_rings[b] = rings
    if rings > 0:
        run_ends[b] = RunEnds()  # unused (find_built searches the rings), but never left unwritten for the next kernel to read
        runs[b] = 0
    else:
        ends, n = sorted_runs(region_vertex, b, region_count[b])
        run_ends[b] = ends
        runs[b] = n


@wp.kernel
def build_batch_elements(
    region_vertex: wp.array2d(dtype=wp.int32), ring_offsets: wp.array2d(dtype=wp.int32), region_count: wp.array(dtype=wp.int32),
    sorted_rings: wp.array(dtype=wp.int32), run_ends: wp.array(dtype=RunEnds), runs: wp.array(dtype=wp.int32), threads: int,
    entry_offsets: wp.array(dtype=wp.int32), entry_topology: wp.array(dtype=wp.vec4i),
    local_offsets: wp.array2d(dtype=wp.int32), local_topology: wp.array2d(dtype=wp.vec4i),
):
    # each region vertex's element entries (a volumetric law's incident tets, in the mesh's entry
    # order, from local_offsets[b, i]), their corners as local indices: every corner of a free vertex's
    # tet is in its region (one ring out); a fixed-ring vertex's tets outside it have corners outside,
    # written -(id + 1) (mesh vertex id: at rest), which only its nodal pressure reads. Thread (b, t)
    # does palpation b's vertices t, t + threads, ... (on CUDA a thread a vertex; on the CPU one a palpation)
    b, t = wp.tid()
    count = region_count[b]
    rings = sorted_rings[b]
    ends = run_ends[b]
    n = runs[b]
    for i in range(t, count, threads):
        v = region_vertex[b, i]
        slot = local_offsets[b, i]
        for k in range(entry_offsets[v], entry_offsets[v + 1]):
            e = entry_topology[k]
            local_topology[b, slot] = wp.vec4i(corner_local(region_vertex, ring_offsets, b, rings, ends, n, count, e[0]),
                                               corner_local(region_vertex, ring_offsets, b, rings, ends, n, count, e[1]),
                                               corner_local(region_vertex, ring_offsets, b, rings, ends, n, count, e[2]),
                                               corner_local(region_vertex, ring_offsets, b, rings, ends, n, count, e[3]))
            slot += 1


ELEMENT_THREADS = 256
"""Threads a palpation of build_batch_elements on CUDA at most (its region's vertices share them)."""


def build_elements(batch, local_offsets, local_topology):
    """Each palpation's region vertices' element entries of `batch`'s volumetric law, as local tets into
    local_topology [B, entry capacity], from their offsets local_offsets [B, vertex capacity + 1] (the
    caller's: a region vertex's first local entry). Two launches: each region's search (its sorted rings
    or runs), then a thread a region vertex on CUDA (a palpation's, up to ELEMENT_THREADS, stride over
    them), one a palpation on the CPU."""
    r, m, B, a = batch.regions, batch.model, batch.batch_size, batch.buffers.array
    sorted_rings, runs = a("element_sorted_rings", B, wp.int32, zero=False), a("element_runs", B, wp.int32, zero=False)
    run_ends = a("element_run_ends", B, RunEnds, zero=False)
    wp.launch(batch_region_runs, dim=B, inputs=[r.region_vertex, r.ring_offsets, r.region_count], outputs=[sorted_rings, run_ends, runs],
              device=batch.device)
    threads = 1
    if batch.device.is_cuda:
        threads = min(max(1 << (int(batch.region_vertex_counts.max(initial=1)) - 1).bit_length(), 32), ELEMENT_THREADS)
    wp.launch(build_batch_elements, dim=(B, threads),
              inputs=[r.region_vertex, r.ring_offsets, r.region_count, sorted_rings, run_ends, runs, threads, m.entry_offsets,
                      m.entry_topology, local_offsets],
              outputs=[local_topology], device=batch.device)


def build_regions(dmesh, seed_offsets, seeds, rings, support, arrays):
    """Build every palpation's region (one launch; `arrays` holds the outputs): ring 0 of palpation b
    is seeds[seed_offsets[b]:seed_offsets[b + 1]] (sorted, unique); `support`: 1 for each held mesh
    vertex, which leaves the free set (a one-element array: none held)."""
    wp.launch(
        build_batch_regions, dim=len(seed_offsets) - 1, inputs=[dmesh.arrays, seed_offsets, seeds, rings, support, arrays.arrays],
        device=dmesh.device,
    )


@wp.kernel
def gather_batch_regions(table: BatchRegionArrays, rows: wp.array(dtype=wp.int32), width: int, threads: int, out: BatchRegionArrays):
    # palpation b's region is row rows[b] of the table, copied whole (capacities equal): its `threads`
    # threads (b, t) copy elements t, t + threads, ... of each of its rows (on CUDA one a word, so
    # consecutive threads write consecutive words; on the CPU one a palpation, a loop)
    b, t = wp.tid()
    r = rows[b]
    j = t
    while j < width:
        if j < out.region_vertex.shape[1]:
            out.region_vertex[b, j] = table.region_vertex[r, j]
        if j < out.local_offsets.shape[1]:
            out.local_offsets[b, j] = table.local_offsets[r, j]
        if j < out.ring_offsets.shape[1]:
            out.ring_offsets[b, j] = table.ring_offsets[r, j]
        if j < out.local_neighbour.shape[1]:
            out.local_neighbour[b, j] = table.local_neighbour[r, j]
            out.local_edge[b, j] = table.local_edge[r, j]
            out.local_owner[b, j] = table.local_owner[r, j]
            out.local_spring[b, j] = table.local_spring[r, j]
            out.spring_entry[b, j] = table.spring_entry[r, j]
        if j == 0:
            out.region_count[b] = table.region_count[r]
            out.free_count[b] = table.free_count[r]
            out.spring_count[b] = table.spring_count[r]
            out.entry_count[b] = table.entry_count[r]
            out.status[b] = table.status[r]
        j += threads


def gather_regions(table, rows, out):
    """Each palpation b of `out` (BatchRegions) takes row rows[b] of `table` (BatchRegions of the same
    capacities, built by build_regions): its region, topology and counts, the same bits (one launch)."""
    width = max(out.region_vertex.shape[1], out.local_offsets.shape[1], out.ring_offsets.shape[1], out.local_neighbour.shape[1])
    threads = width if rows.device.is_cuda else 1
    wp.launch(gather_batch_regions, dim=(len(rows), threads), inputs=[table.arrays, rows, width, threads, out.arrays],
              device=rows.device)


@wp.kernel
def rest_batch_state(
    regions: BatchRegionArrays,
    tissue: TissueArrays,
    press: BatchPress,
    q_state: wp.array2d(dtype=wp.vec3), qd_state: wp.array2d(dtype=wp.vec3),
):
    # every region vertex at rest, the probe's records cleared
    b = wp.tid()
    for i in range(regions.region_count[b]):
        q_state[b, i] = tissue.q_rest[regions.region_vertex[b, i]]
        qd_state[b, i] = wp.vec3(0.0)
    press.peak_force[b] = wp.float64(0.0)
    press.peak_reaction[b] = wp.vec3(0.0)
    press.hold_reaction[b] = wp.vec3(0.0)


def rest_states(batch):
    """Put every palpation's region at rest and clear its force records."""
    wp.launch(
        rest_batch_state,
        dim=batch.batch_size,
        inputs=[batch.regions.arrays, batch.model.arrays, batch.press_arrays],
        outputs=[batch.q_state, batch.qd_state],
        device=batch.device,
    )


@wp.kernel
def batch_ring_gaps(regions: BatchRegionArrays, rings: int, q_rest: wp.array(dtype=wp.vec3), centre: wp.array(dtype=wp.vec3),
                    radius: float, gap: wp.array(dtype=float)):
    # palpation b's sphere at `centre` [b]: its least distance from a vertex (at rest) of the region's outer
    # ring (the last non-empty one; support-held vertices are not a ring's), less the radius; 1e30 with none
    b = wp.tid()
    count = regions.region_count[b]
    start = count
    for r in range(rings, 0, -1):
        if start == count and regions.ring_offsets[b, r] < count:
            start = regions.ring_offsets[b, r]
    best = float(1.0e30)
    for k in range(start, count):
        best = wp.min(best, wp.length(q_rest[regions.region_vertex[b, k]] - centre[b]))
    gap[b] = best - radius


def ring_gaps(batch, centres: wp.array, out: wp.array) -> None:
    """PressResult.ring_gap of each palpation of `batch` (its regions, rings, model and sphere), its
    sphere's centre at full depth given, into `out` (a [B] float device array)."""
    wp.launch(batch_ring_gaps, dim=batch.batch_size, inputs=[batch.regions.arrays, batch.rings, batch.model.particle_q_rest, centres,
                                                            float(batch.probe_radius)], outputs=[out], device=batch.device)


@wp.kernel
def offset_item_regions(regions: BatchRegionArrays, item: wp.array(dtype=wp.int32), vertex_stride: int, edge_stride: int):
    # palpation b presses item item[b] of a stack of models of one mesh (almsdm_warp/batch/item_batch.py): its
    # region's vertices and springs become that item's, vertex v at item * vertex_stride + v, spring s at
    # item * edge_stride + s; the local topology (neighbours, codes, counts) stays as built
    b, j = wp.tid()
    k = item[b]
    if j < regions.region_count[b]:
        regions.region_vertex[b, j] = regions.region_vertex[b, j] + k * vertex_stride
    if j < regions.entry_count[b]:
        regions.local_edge[b, j] = regions.local_edge[b, j] + k * edge_stride


def offset_regions(regions, item, vertex_stride: int, edge_stride: int):
    """Make each palpation b of `regions` (BatchRegions built on one mesh) read item item[b]'s copy of the
    mesh in a stack of K copies (int32 device array [B]): vertex ids + item x vertex_stride, edge ids +
    item x edge_stride (one launch, in place)."""
    width = max(regions.region_vertex.shape[1], regions.local_edge.shape[1])
    wp.launch(offset_item_regions, dim=(len(item), width), inputs=[regions.arrays, item, int(vertex_stride), int(edge_stride)],
              device=item.device)
