"""A region's tets for a volumetric law's step on the CPU: each tet's volume and forces once a step.

The pass of kernels/explicit/step.py (`nodal_pressure`, kernels/laws/tets.py) sums, for each region
vertex, its incident tets' deformed volumes: a tet is computed once for each of its region corners
(on the tet ball of scripts/bench_laws.py, 2,087 volumes a step for 737 tets), and the tets with no
free corner, most of a fixed-ring vertex's, do not change while the region stays. Here the region's
tets are listed once, when its free set is set (`build_region_tets`, one thread):
- the *active* tets, those with a free corner, each once (by its first free corner in local order),
  in their own corner order;
- each entry of a region vertex gets a slot in `volume6`: its tet's among the active ones, or, for a
  tet with no free corner, a slot of its own holding that tet's volume at the build, which no step
  changes (the vertices outside the free set do not move while the region stays: a protocol that
  moves the free set builds again).
A step is then three passes (`tet_pass_kernel`, one launch on one thread, else one each): each active
tet's volume; each region vertex's sum of its entries' slots in entry order and its nodal pressure
(nodal_value, the law's); each active tet's forces on its four corners, its stress once (the law's
tet_forces), which the step's gather then sums for each free vertex in entry order (gathered_force,
kernels/laws/tets.py) in place of a tet's force computed at each of its free corners. Grid-stride
as the step; the build is one thread, so a CUDA step keeps going over each vertex's tets, which runs
in parallel there (SolverExplicit.tet_pass chooses). The volumes and forces are the same functions of
the positions as the per-vertex pass's; each tet is rounded once, in its own corner order, not once a
corner.
"""

import functools

import warp as wp

from ..arrays import RegionTetArrays
from ..index import nonneg
from ..laws import LAWS
from ..laws.tets import ENTRY_PARAMS, TetRest, nodal_value, tet_pressure, tet_volume6

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def free_before(vertex_local: wp.array(dtype=wp.int32), c: int, limit: int):
    # whether mesh vertex c is free with a local index under `limit` (vertex_local: -1 outside the region)
    lc = vertex_local[nonneg(c)]
    return lc >= 0 and lc < limit


@wp.func
def corner_of(c: wp.vec4i, v: int):
    # which corner of the tet c vertex v is
    m = int(0)
    for j in range(1, 4):
        if c[j] == v:
            m = j
    return m


@wp.kernel
def build_region_tets(
    free_vertex: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), vertex_local: wp.array(dtype=wp.int32),
    entry_offsets: wp.array(dtype=wp.int32), entry_tet: wp.array(dtype=wp.int32), tet_corners: wp.array(dtype=wp.vec4i),
    q: wp.array(dtype=wp.vec3), out: RegionTetArrays,
):
    # one thread: the active tets, each by its first free corner in local order, then the fixed ring's entries
    free = counts[0]
    active = int(0)
    for i in range(free):
        v = free_vertex[i]
        for k in range(entry_offsets[v], entry_offsets[v + 1]):
            t = entry_tet[k]
            c = tet_corners[t]
            if not (free_before(vertex_local, c[0], i) or free_before(vertex_local, c[1], i)
                    or free_before(vertex_local, c[2], i) or free_before(vertex_local, c[3], i)):
                out.tets[active] = c
                out.tet_id[active] = t
                out.tet_slot[t] = active
                active += 1
            out.entry_slot[k] = out.tet_slot[t]
            out.entry_corner[k] = 4 * out.tet_slot[t] + corner_of(c, v)
    out.count[0] = active
    slot = active
    for i in range(free, counts[1]):
        v = free_vertex[i]
        for k in range(entry_offsets[v], entry_offsets[v + 1]):
            t = entry_tet[k]
            c = tet_corners[t]
            if (free_before(vertex_local, c[0], free) or free_before(vertex_local, c[1], free)
                    or free_before(vertex_local, c[2], free) or free_before(vertex_local, c[3], free)):
                out.entry_slot[k] = out.tet_slot[t]
            else:
                out.volume6[slot] = tet_volume6(q[c[0]], q[c[1]], q[c[2]], q[c[3]])
                out.entry_slot[k] = slot
                slot += 1


@wp.func
def active_volumes(out: RegionTetArrays, thread: int, stride: int, q: wp.array(dtype=wp.vec3)):
    # each active tet's six volumes at q (grid-stride; while loops: fewer instructions than range() on the CPU)
    s = thread
    count = out.count[0]
    while s < count:
        c = out.tets[nonneg(s)]
        out.volume6[nonneg(s)] = tet_volume6(q[nonneg(c[0])], q[nonneg(c[1])], q[nonneg(c[2])], q[nonneg(c[3])])
        s += stride


@wp.func
def slot_pressures(region_vertex: wp.array(dtype=wp.int32), count: int, thread: int, stride: int, entry_offsets: wp.array(dtype=wp.int32),
                   entry_params: ENTRY_PARAMS, out: RegionTetArrays, pressure: wp.array(dtype=wp.float32)):
    # each region vertex's nodal pressure from its entries' slots, in entry order
    i = thread
    while i < count:
        v = nonneg(region_vertex[nonneg(i)])
        begin = entry_offsets[v]
        end = entry_offsets[v + 1]
        p = float(0.0)
        if begin < end:
            volume6 = float(0.0)
            k = begin
            while k < end:
                volume6 += out.volume6[nonneg(out.entry_slot[nonneg(k)])]
                k += 1
            p = nodal_value(volume6, entry_params[nonneg(begin)].nodal)
        pressure[v] = p
        i += stride


@functools.cache
def tet_pass_kernel(law: str):
    """The per-tet passes of tet law `law` over a listed region (RegionTets), in phases: 1 the active
    tets' volumes, 2 the region vertices' nodal pressures from them, 4 each active tet's forces on its
    corners (the law's tet_forces, the mean of its corners' pressures); one thread runs them all in
    one launch (phases 7), more threads one phase a launch."""
    tet_forces = LAWS[law].tet_forces

    @wp.kernel(module="unique", enable_backward=False)
    def region_tet_pass(
        region_vertex: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), stride: int, entry_offsets: wp.array(dtype=wp.int32),
        entry_params: ENTRY_PARAMS, tet_rest: wp.array(dtype=TetRest), out: RegionTetArrays, q: wp.array(dtype=wp.vec3), phases: int,
        pressure: wp.array(dtype=wp.float32),
    ):
        if phases & 1:
            active_volumes(out, wp.tid(), stride, q)
        if phases & 2:
            slot_pressures(region_vertex, counts[1], wp.tid(), stride, entry_offsets, entry_params, out, pressure)
        if phases & 4:
            s = wp.tid()
            count = out.count[0]
            while s < count:
                c = out.tets[nonneg(s)]
                f0, f1, f2, f3 = tet_forces(q[nonneg(c[0])], q[nonneg(c[1])], q[nonneg(c[2])], q[nonneg(c[3])],
                                            tet_rest[nonneg(out.tet_id[nonneg(s)])], tet_pressure(c, pressure))
                b = 4 * nonneg(s)
                out.force[b] = f0
                out.force[b + 1] = f1
                out.force[b + 2] = f2
                out.force[b + 3] = f3
                s += stride

    return region_tet_pass


class RegionTets:
    """The arrays of one region's tets (RegionTetArrays), sized for any region of `model`'s mesh."""

    def __init__(self, model):
        entry_tet, tet_corners, tet_rest = model.entry_tets()
        d = model.device
        entries, tets = int(entry_tet.shape[0]), int(tet_corners.shape[0])
        self.model, self.entry_tet, self.tet_corners, self.tet_rest = model, entry_tet, tet_corners, tet_rest
        self.arrays = RegionTetArrays()
        self.arrays.tets = wp.zeros(tets, dtype=wp.vec4i, device=d)
        self.arrays.count = wp.zeros(1, dtype=wp.int32, device=d)
        self.arrays.entry_slot = wp.zeros(entries, dtype=wp.int32, device=d)
        self.arrays.volume6 = wp.zeros(entries, dtype=wp.float32, device=d)
        self.arrays.tet_slot = wp.zeros(tets, dtype=wp.int32, device=d)
        self.arrays.tet_id = wp.zeros(tets, dtype=wp.int32, device=d)
        self.arrays.entry_corner = wp.zeros(entries, dtype=wp.int32, device=d)
        self.arrays.force = wp.zeros(4 * tets, dtype=wp.vec3, device=d)

    def build(self, free_vertex, counts, vertex_local, q) -> None:
        """List the tets of the region whose free vertices are the first counts[0] of `free_vertex`
        (its first counts[1] the region's, free and fixed ring; vertex_local: each mesh vertex's index
        in it, -1 outside), the fixed ones' volumes at positions `q`."""
        m = self.model
        wp.launch(build_region_tets, dim=1, inputs=[free_vertex, counts, vertex_local, m.entry_offsets, self.entry_tet, self.tet_corners, q,
                                                     self.arrays], device=m.device)

    def pressures(self, region_vertex, counts, threads: int, q, forces: bool = False) -> None:
        """The nodal pressures (model.nodal_pressure) of the first counts[1] vertices of `region_vertex`
        at positions `q`, and with `forces` each listed tet's forces on its corners (arrays.force): the
        region built last (build). One launch on one thread, else one a phase."""
        m = self.model
        phases = (1, 2, 4) if forces else (1, 2)
        kernel = tet_pass_kernel(m.law)
        for phase in ((sum(phases),) if threads == 1 else phases):
            wp.launch(kernel, dim=threads, inputs=[region_vertex, counts, threads, m.entry_offsets, m.entry_params, self.tet_rest, self.arrays,
                                                   q, phase], outputs=[m.nodal_pressure], device=m.device)
