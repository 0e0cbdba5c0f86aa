"""A batch of presses, implicit (backward) Euler: one thread per palpation, one step per launch.

The one-region implicit step's composition (kernels/implicit/step.py) on each palpation's compacted region:
linearized once per step (Baraff & Witkin), (M + dt C + dt^2 K) dv = dt (f0 - dt K v0),
block-Jacobi preconditioned conjugate gradients warm-started from the palpation's previous dv;
the driven vertex (local 0 while the probe presses) is a known velocity, the fixed ring has
dv = 0. A sphere (BatchSphere, radius > 0) drives no vertex: it holds each free surface vertex
it contains along its normal, as the one-region step does (kernels/probes/sphere.py), and the
feedback force is the sum of the contact reactions. The same expressions and the same order of every sum (vertices in local order, each
vertex's springs in mesh CSR order), so a palpation of the batch gives the same bits as
``Palpation(..., integrator="implicit").press`` on the CPU.
"""

import functools

import warp as wp

from ..arrays import BatchCGArrays, BatchElements, BatchPress, BatchRecords, BatchRegionArrays, BatchSphere, TissueArrays
from ..laws import LAWS
from ..probes.press import drive_vertex, press_target, record_curve, record_peak
from ..probes.sphere import sphere_constrain
from .block_cg import solve_block_cg
from .step import CONTACT_SLACK, implicit_rhs, implicit_update

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def record_force(press: BatchPress, b: int, step: int, f: wp.vec3):
    # palpation b's feedback force at `step` into its records: the peak (kernels/probes/press.py) and the hold's
    peak2, peak_f = record_peak(press.peak_force[b], press.peak_reaction[b], f)
    press.peak_force[b] = peak2
    press.peak_reaction[b] = peak_f
    if step == press.press_steps - 1:
        press.hold_reaction[b] = f


@functools.cache
def batch_kernel(law: str, records: bool = False):
    """The implicit batch step of tissue law `law` (a key of kernels.laws.LAWS); `records`: with the
    force curve of the learning records (BatchRecords; a variant of its own, as the explicit batch's)."""
    RECORDS = bool(records)
    implicit_row, nodal_pressure, Entries = LAWS[law].implicit_row, LAWS[law].nodal_pressure, LAWS[law].Entries
    SPRINGS = not LAWS[law].VOLUMETRIC  # its entries are the rows'; a volumetric law's tets are the batch's element arrays

    @wp.kernel(module="unique", enable_backward=False)
    def step_batch_implicit(
        regions: BatchRegionArrays,
        tissue: TissueArrays,
        anchor_scale: float,
        press: BatchPress,
        probe: BatchSphere,
        step: int,
        max_iterations: int,
        tolerance: float,
        q_in: wp.array2d(dtype=wp.vec3),
        qd_in: wp.array2d(dtype=wp.vec3),
        cg: BatchCGArrays,
        entries: Entries,
        elements: BatchElements,
        records: BatchRecords,
        q_out: wp.array2d(dtype=wp.vec3),
        qd_out: wp.array2d(dtype=wp.vec3),
    ):
        b = wp.tid()
        dt = press.dt
        free_n = regions.free_count[b]
        driven = int(-1)
        dv_driven = wp.vec3(0.0)
        target = wp.vec3(0.0)
        constrained = int(0)
        reaction = wp.vec3(0.0)
        if step < press.press_steps:
            direction = press.press_direction[b]
            if probe.radius > 0.0:
                # the sphere's centre: touching the surface at the contact vertex at rest, then along the press
                start = wp.vec3d(tissue.q_rest[regions.region_vertex[b, probe.contact_local[b]]]) - direction * probe.radius64
                target = press_target(start, direction, press.depth, step, press.ramp_steps)
                constrained = 1
            else:
                # local vertex 0 is driven
                target = press_target(wp.vec3d(tissue.q_rest[regions.region_vertex[b, 0]]), direction, press.depth, step, press.ramp_steps)
                driven = 0
                dv_driven = (target - q_in[b, 0]) / dt - qd_in[b, 0]

        # 0) a volumetric law's nodal pressures over the region's vertices (free and fixed ring)
        pressure = elements.pressure[b]
        if wp.static(not SPRINGS):
            for i in range(regions.region_count[b]):
                pressure[i] = nodal_pressure(elements.offsets[b, i], elements.offsets[b, i + 1], elements.topology[b], entries.params,
                                             elements.shift[b, i], q_in[b], tissue.q_rest)

        # 1) forces, diagonal blocks and right-hand side b = dt (f0 - dt K v0) - A_ic dv_c
        neighbour = regions.local_neighbour[b]
        b_norm2 = float(0.0)
        for i in range(free_n):
            v = regions.region_vertex[b, i]
            x = q_in[b, i]
            u = qd_in[b, i]
            k0 = regions.local_offsets[b, i]
            f = wp.vec3(0.0)
            D = wp.mat33(0.0)
            Kv = wp.vec3(0.0)
            correction = wp.vec3(0.0)
            if wp.static(SPRINGS):
                # the springs from the mesh's CSR table: a free vertex's local entries are its mesh entries in order
                f, D, Kv, correction = implicit_row(
                    x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale, tissue.particle_mass[v], dt,
                    k0, regions.local_offsets[b, i + 1], neighbour, tissue.adj_spring, tissue.adj_offsets[v] - k0,
                    k0, regions.local_offsets[b, i + 1], neighbour, q_in[b], qd_in[b],
                    neighbour, 1, i, driven, dv_driven, free_n, cg.csr_block[b], cg.csr_local[b], 0, pressure,
                )
            else:
                # the tets from the batch's element arrays (local corners), their rest data the mesh's
                f, D, Kv, correction = implicit_row(
                    x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale, tissue.particle_mass[v], dt,
                    elements.offsets[b, i], elements.offsets[b, i + 1], elements.topology[b], entries.params, elements.shift[b, i],
                    k0, regions.local_offsets[b, i + 1], neighbour, q_in[b], qd_in[b],
                    neighbour, 1, i, driven, dv_driven, free_n, cg.csr_block[b], cg.csr_local[b], 0, pressure,
                )
            if i == 0 and driven == 0:
                record_force(press, b, step, f)  # the feedback force: internal forces on the probe's vertex
                if wp.static(RECORDS):
                    record_curve(records, b, step, press.ramp_steps, f)
            cg.diag[b, i] = D
            cg.diag_inv[b, i] = wp.inverse(D)
            rhs = implicit_rhs(f, Kv, correction, dt)
            if i == driven:
                rhs = wp.vec3(0.0)
            if constrained != 0:
                # a vertex the sphere holds: its normal velocity prescribed, so that the step ends on the sphere
                n_c = wp.vec3(0.0)
                if probe.probe_surface[v] != 0:
                    n_c, dv_w, rhs, contact = sphere_constrain(x, u, f, rhs, cg.dv[b, i], target, probe.radius, CONTACT_SLACK, dt)
                    cg.dv[b, i] = dv_w
                    reaction += contact
                cg.normal[b, i] = n_c
            cg.r[b, i] = rhs
            b_norm2 += wp.dot(rhs, rhs)

        # 2) and 3): r = b - A dv (warm start), then conjugate gradients (kernels/implicit/block_cg.py), on this palpation's rows
        solve_block_cg(
            free_n, driven, regions.local_offsets[b], regions.local_offsets[b], 0, cg.csr_local[b], cg.csr_block[b], cg.diag[b], cg.diag_inv[b],
            constrained, cg.normal[b], b_norm2, max_iterations, tolerance, cg.dv[b], cg.r[b], cg.p[b], cg.Ap[b],
        )

        if constrained != 0:
            record_force(press, b, step, reaction)  # the feedback force: the sum of the contact reactions
            if wp.static(RECORDS):
                record_curve(records, b, step, press.ramp_steps, reaction)

        # 4) v1 = v0 + dv, x1 = x0 + dt v1; the driven vertex goes where the probe puts it
        for i in range(free_n):
            x = q_in[b, i]
            if i == driven:
                xd, ud = drive_vertex(x, target, dt)
                q_out[b, i] = xd
                qd_out[b, i] = ud
            else:
                n_h = wp.vec3(0.0)
                if constrained != 0:
                    n_h = cg.normal[b, i]
                x1, u1 = implicit_update(x, qd_in[b, i], cg.dv[b, i], n_h, target, probe.radius, dt)
                q_out[b, i] = x1
                qd_out[b, i] = u1

    return step_batch_implicit


def step_batch(batch, step, state_in, state_out, scratch, max_iterations, tolerance):
    """One implicit step of every palpation of `batch`: state_in -> state_out, (q, qd) pairs."""
    m, r, p = batch.model, batch.regions, batch
    wp.launch(
        batch_kernel(m.law, p.records.on),
        dim=p.batch_size,
        inputs=[
            r.arrays, m.arrays, 1.0, p.press_arrays, p.sphere_arrays, int(step), int(max_iterations), float(tolerance),
            state_in[0], state_in[1], scratch.arrays, m.entries, p.elements, p.records.arrays,
        ],
        outputs=[state_out[0], state_out[1]],
        device=m.device,
    )
