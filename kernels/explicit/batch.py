"""A batch of presses, semi-implicit Euler, exact: one block per palpation, many steps in one launch.

The reference batch kernel: the CPU's, and CUDA's where a batch's regions do not fit the fast
kernel (kernels/explicit/batch_fast.py).

Each palpation's region (its state, rest positions, masses, anchors and the local topology of
its free vertices: neighbour local index and spring parameters per CSR entry) is loaded once
into working arrays, stepped `step_count` times with a block barrier between steps, and written
back. On CUDA the working arrays are in shared memory (native snippets declare them and
give Warp an array view of them: kernels/block_memory.py) and a block's threads share the free vertices; elsewhere
(the CPU, or regions too large for shared memory) they are per-palpation slices of global
scratch arrays and a block is one thread.

It is the one-region step's composition (kernels/explicit/step.py) on a batch's layout: the law's
`vertex_force` (kernels/laws) over each free vertex's local CSR entries, `advance`, the driven vertex
and the press's schedule and force record (kernels/probes/press.py), the sphere's contact
(kernels/probes/sphere.py). So a batch gives the same bits as ``Palpation.press`` on the same
device (tests/test_batch.py).
"""

import functools

import warp as wp

from ..arrays import BatchElements, BatchPress, BatchRecords, BatchRegionArrays, BatchSphere, TissueArrays
from ..block_memory import SHARED_BYTES_MAX, block_sync, work_array
from ..laws import LAWS
from ..probes.press import drive_vertex, press_target, record_contact, record_curve, record_peak
from ..probes.sphere import sphere_contact_step
from .step import advance

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

__all__ = ["SHARED_BYTES_MAX", "press_batch", "press_kernel", "scratch_sizes", "shared_bytes"]


@functools.cache
def press_kernel(law: str, vertex_capacity: int, entry_capacity: int, shared: bool, sphere: bool = False, records: bool = False):
    """The batch press kernel of tissue law `law` (a key of kernels.laws.LAWS) for regions of up to
    `vertex_capacity` vertices and `entry_capacity` CSR entries of free vertices; working arrays in
    shared memory on CUDA when `shared`. `sphere`: the probe is a sphere (BatchSphere; no vertex
    driven, a contact pass after each pressed step), a variant of its own so that the paper's probe
    runs none of it. `records`: the learning records (BatchRecords: the force curve, and with a
    sphere the contact patch and tactile map), a variant of its own so that a press without them
    runs none of it (the same code, speed and bits as before)."""
    SPHERE = bool(sphere)
    RECORDS = bool(records)
    PATCH = RECORDS and SPHERE
    VOLUMETRIC = LAWS[law].VOLUMETRIC
    SPRINGS = not VOLUMETRIC  # its springs in the working arrays; a volumetric law's tets read from the batch's element arrays
    cv, ce, cp = work_sizes(vertex_capacity, entry_capacity, VOLUMETRIC)
    vertex_force, nodal_pressure, Entries, PARAMS = (LAWS[law].vertex_force, LAWS[law].nodal_pressure, LAWS[law].Entries,
                                                     LAWS[law].ENTRY_PARAMS)

    @wp.func
    def substep(
        lane: int, threads: int, n: int, nf: int, off: wp.array(dtype=wp.int32), nbr: wp.array(dtype=wp.int32),
        spring: wp.array(dtype=wp.vec3), q_rest: wp.array(dtype=wp.vec3), particle_mass: wp.array(dtype=wp.float32),
        anchor_ke: wp.array(dtype=wp.float32), anchor_kd: wp.array(dtype=wp.float32), anchor_scale: float,
        pressed: int, target: wp.vec3, dt: float,
        q_in: wp.array(dtype=wp.vec3), qd_in: wp.array(dtype=wp.vec3), q_out: wp.array(dtype=wp.vec3), qd_out: wp.array(dtype=wp.vec3),
        element_offsets: wp.array(dtype=wp.int32), element_topology: wp.array(dtype=wp.vec4i), params: PARAMS,
        shift: wp.array(dtype=wp.int32), pressure: wp.array(dtype=wp.float32), mesh_rest: wp.array(dtype=wp.vec3),
    ):
        # one step of the free vertices this lane owns; returns the reaction on local vertex 0 (the
        # probe's), which lane 0 owns. Local indices: arrays are the region's, not the mesh's (a
        # volumetric law's entry parameters are the mesh's: `shift` takes a local entry there). A
        # volumetric law's nodal pressures first, over all n region vertices (a fixed-ring vertex's
        # tets outside the region have negative corners: mesh vertices at rest, mesh_rest).
        if wp.static(VOLUMETRIC):
            for i in range(lane, n, threads):
                pressure[i] = nodal_pressure(element_offsets[i], element_offsets[i + 1], element_topology, params, shift[i], q_in, mesh_rest)
            block_sync()
        reaction = wp.vec3(0.0)
        for i in range(lane, nf, threads):
            x = q_in[i]
            u = qd_in[i]
            f = wp.vec3(0.0)
            if wp.static(SPRINGS):
                f = vertex_force(x, u, q_rest[i], anchor_ke[i], anchor_kd[i], anchor_scale, off[i], off[i + 1], nbr, spring, 0, q_in, qd_in,
                                 pressure)
            else:
                f = vertex_force(x, u, q_rest[i], anchor_ke[i], anchor_kd[i], anchor_scale, element_offsets[i], element_offsets[i + 1],
                                 element_topology, params, shift[i], q_in, qd_in, pressure)
            if i == 0 and pressed != 0:
                reaction = f  # the feedback force: the tissue's internal forces on the probe
                xd, ud = drive_vertex(x, target, dt)  # displacement control
                q_out[i] = xd
                qd_out[i] = ud
            else:
                x1, u1 = advance(x, u, dt * f / particle_mass[i], dt)
                q_out[i] = x1
                qd_out[i] = u1
        return reaction

    @wp.func
    def contact(
        nf: int, region_vertex: wp.array2d(dtype=wp.int32), b: int, probe_surface: wp.array(dtype=wp.int32),
        particle_mass: wp.array(dtype=wp.float32), centre: wp.vec3, radius: float, dt: float,
        q_in: wp.array(dtype=wp.vec3), qd_in: wp.array(dtype=wp.vec3), q_out: wp.array(dtype=wp.vec3), qd_out: wp.array(dtype=wp.vec3),
        records: BatchRecords, hold: int, direction: wp.vec3,
    ):
        # the sphere after the step (one thread, local order, as the one-region contact pass): each
        # free surface vertex inside it onto its surface; returns the sum of the contact reactions
        # (with records, at the hold's last step: each contact into the patch and the tactile map)
        total = wp.vec3(0.0)
        for i in range(nf):
            if probe_surface[region_vertex[b, i]] != 0:
                x1, u1, c, touched = sphere_contact_step(q_in[i], qd_in[i], q_out[i], qd_out[i], particle_mass[i], centre, radius, dt)
                if touched:
                    q_out[i] = x1
                    qd_out[i] = u1
                    total += c
                    if wp.static(PATCH):
                        if hold != 0 and records.map_size > 0:
                            record_contact(records, b, region_vertex[b, i], x1, c, centre, direction, radius)
        return total

    w_q_a = work_array("q_a", wp.vec3, cv, shared)
    w_qd_a = work_array("qd_a", wp.vec3, cv, shared)
    w_q_b = work_array("q_b", wp.vec3, cv, shared)
    w_qd_b = work_array("qd_b", wp.vec3, cv, shared)
    w_rest = work_array("rest", wp.vec3, cv, shared)
    w_mass = work_array("mass", wp.float32, cv, shared)
    w_ka = work_array("ka", wp.float32, cv, shared)
    w_kda = work_array("kda", wp.float32, cv, shared)
    w_pressure = work_array("pressure", wp.float32, cp, shared)
    w_spring = work_array("spring", wp.vec3, ce, shared)
    w_off = work_array("off", wp.int32, cv + 1, shared)
    w_nbr = work_array("nbr", wp.int32, ce, shared)

    @wp.kernel(module="unique", enable_backward=False)
    def press_batch_explicit(
        threads: int,
        regions: BatchRegionArrays,
        tissue: TissueArrays,
        anchor_scale: float,
        press: BatchPress,
        probe: BatchSphere,
        step_begin: int,
        step_count: int,
        scratch_vec3: wp.array(dtype=wp.vec3),
        scratch_float: wp.array(dtype=wp.float32),
        scratch_int: wp.array(dtype=wp.int32),
        entries: Entries,
        elements: BatchElements,
        records: BatchRecords,
        q_state: wp.array2d(dtype=wp.vec3),
        qd_state: wp.array2d(dtype=wp.vec3),
    ):
        tid = wp.tid()
        b = tid // threads
        lane = tid - b * threads
        n = regions.region_count[b]
        nf = regions.free_count[b]
        ne = regions.local_offsets[b, nf]
        # working arrays (shared memory on CUDA; offsets are used only by the global fallback)
        q_a = w_q_a(scratch_vec3, b * (5 * cv + ce))
        qd_a = w_qd_a(scratch_vec3, b * (5 * cv + ce) + cv)
        q_b = w_q_b(scratch_vec3, b * (5 * cv + ce) + 2 * cv)
        qd_b = w_qd_b(scratch_vec3, b * (5 * cv + ce) + 3 * cv)
        rest = w_rest(scratch_vec3, b * (5 * cv + ce) + 4 * cv)
        spring = w_spring(scratch_vec3, b * (5 * cv + ce) + 5 * cv)
        mass = w_mass(scratch_float, b * (3 * cv + cp))
        ka = w_ka(scratch_float, b * (3 * cv + cp) + cv)
        kda = w_kda(scratch_float, b * (3 * cv + cp) + 2 * cv)
        pressure = w_pressure(scratch_float, b * (3 * cv + cp) + 3 * cv)
        off = w_off(scratch_int, b * (cv + 1 + ce))
        nbr = w_nbr(scratch_int, b * (cv + 1 + ce) + cv + 1)
        # load the region once: state, per-vertex parameters, local topology with spring parameters
        for i in range(lane, n, threads):
            v = regions.region_vertex[b, i]
            rest[i] = tissue.q_rest[v]
            mass[i] = tissue.particle_mass[v]
            ka[i] = tissue.anchor_ke[v]
            kda[i] = tissue.anchor_kd[v]
            q_a[i] = q_state[b, i]
            qd_a[i] = qd_state[b, i]
            q_b[i] = q_state[b, i]
            qd_b[i] = qd_state[b, i]
        if wp.static(SPRINGS):
            for i in range(lane, nf + 1, threads):
                off[i] = regions.local_offsets[b, i]
            for k in range(lane, ne, threads):
                nbr[k] = regions.local_neighbour[b, k]
                e = regions.local_edge[b, k]
                spring[k] = wp.vec3(tissue.spring_ke[e], tissue.spring_kd[e], tissue.spring_rest_length[e])
        block_sync()
        eoff = elements.offsets[b]
        etop = elements.topology[b]
        eshift = elements.shift[b]

        dt = press.dt
        rest0 = wp.vec3d(rest[0])
        direction = press.press_direction[b]
        if wp.static(SPHERE):
            # the sphere's centre at rest: touching the surface at the contact vertex
            rest0 = wp.vec3d(rest[probe.contact_local[b]]) - direction * probe.radius64
        peak = press.peak_force[b]
        peak_f = press.peak_reaction[b]
        for s in range(step_begin, step_begin + step_count):
            pressed = int(0)
            target = wp.vec3(0.0)
            if s < press.press_steps:
                pressed = 1
                target = press_target(rest0, direction, press.depth, s, press.ramp_steps)
            driven = pressed
            if wp.static(SPHERE):
                driven = 0
            if (s - step_begin) % 2 == 0:
                f = substep(lane, threads, n, nf, off, nbr, spring, rest, mass, ka, kda, anchor_scale, driven, target, dt, q_a, qd_a, q_b, qd_b,
                            eoff, etop, entries.params, eshift, pressure, tissue.q_rest)
            else:
                f = substep(lane, threads, n, nf, off, nbr, spring, rest, mass, ka, kda, anchor_scale, driven, target, dt, q_b, qd_b, q_a, qd_a,
                            eoff, etop, entries.params, eshift, pressure, tissue.q_rest)
            if wp.static(SPHERE):
                if pressed != 0:
                    block_sync()
                    if lane == 0:
                        rv = regions.region_vertex
                        hold = int(s == press.press_steps - 1)
                        d = wp.vec3(direction)
                        if (s - step_begin) % 2 == 0:
                            f = contact(nf, rv, b, probe.probe_surface, mass, target, probe.radius, dt, q_a, qd_a, q_b, qd_b, records, hold, d)
                        else:
                            f = contact(nf, rv, b, probe.probe_surface, mass, target, probe.radius, dt, q_b, qd_b, q_a, qd_a, records, hold, d)
            if lane == 0 and pressed != 0:
                peak, peak_f = record_peak(peak, peak_f, f)
                if wp.static(RECORDS):
                    record_curve(records, b, s, press.ramp_steps, f)
                if s == press.press_steps - 1:
                    press.hold_reaction[b] = f
            block_sync()
        # write the state back (the last step wrote b when step_count is odd)
        odd = step_count % 2
        for i in range(lane, n, threads):
            if odd == 1:
                q_state[b, i] = q_b[i]
                qd_state[b, i] = qd_b[i]
            else:
                q_state[b, i] = q_a[i]
                qd_state[b, i] = qd_a[i]
        if lane == 0:
            press.peak_force[b] = peak
            press.peak_reaction[b] = peak_f

    return press_batch_explicit


def work_sizes(vertex_capacity: int, entry_capacity: int, volumetric: bool):
    """(vertices, spring entries, pressures) of a block's working arrays: a volumetric law keeps no
    springs (its tets are the batch's element arrays) and a nodal pressure a vertex; springs none."""
    cv = int(vertex_capacity)
    return (cv, 1, cv) if volumetric else (cv, int(entry_capacity), 1)


def scratch_sizes(batch: int, vertex_capacity: int, entry_capacity: int, shared: bool, volumetric: bool = False):
    """Element counts of the global scratch arrays (vec3, float32, int32); 1 each when in shared memory."""
    if shared:
        return 1, 1, 1
    cv, ce, cp = work_sizes(vertex_capacity, entry_capacity, volumetric)
    return batch * (5 * cv + ce), batch * (3 * cv + cp), batch * (cv + 1 + ce)


def shared_bytes(vertex_capacity: int, entry_capacity: int, volumetric: bool = False) -> int:
    """Shared memory a block of the press kernel takes [bytes]."""
    cv, ce, cp = work_sizes(vertex_capacity, entry_capacity, volumetric)
    return (5 * cv + ce) * 12 + (3 * cv + cp) * 4 + (cv + 1 + ce) * 4


def press_batch(batch, step_begin, step_count):
    """Advance every palpation of `batch` (an almsdm_warp.batch.batch_palpation.BatchPalpation) `step_count` steps."""
    m, r, p = batch.model, batch.regions, batch
    kernel = press_kernel(m.law, p.vertex_capacity, p.entry_capacity, p.shared, p.probe_radius > 0, p.records.on)
    wp.launch(
        kernel,
        dim=p.batch_size * p.threads,
        block_dim=p.threads,
        inputs=[p.threads, r.arrays, m.arrays, 1.0, p.press_arrays, p.sphere_arrays, int(step_begin), int(step_count), p.scratch_vec3,
                p.scratch_float, p.scratch_int, m.entries, p.elements, p.records.arrays],
        outputs=[p.q_state, p.qd_state],
        device=m.device,
    )


@wp.kernel
def gather_contact_q(q_state: wp.array2d(dtype=wp.vec3), contact_local: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.vec3)):
    # each palpation's contact vertex position (its local index: 0 for the paper's probe, anywhere in a sphere's ring 0)
    b = wp.tid()
    out[b] = q_state[b, contact_local[b]]


def contact_positions(batch):
    """Each palpation's contact vertex position [m], a [B] vec3 device array (on the current stream;
    the batch's own from one press to the next: batch.buffers)."""
    out = batch.buffers.array("contact_positions", batch.batch_size, wp.vec3, zero=False)
    wp.launch(gather_contact_q, dim=batch.batch_size, inputs=[batch.q_state, batch.contact_local], outputs=[out], device=batch.device)
    return out
