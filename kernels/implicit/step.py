"""Implicit (backward) Euler on the region's free vertices, with a matrix-free CG solve.

Linearized once per step (Baraff & Witkin): (M + dt C + dt^2 K) dv = dt (f0 - dt K v0), with
K = -df/dx (the tissue law's blocks, kernels/laws: positive semi-definite) and
C = -df/dv. Block-Jacobi preconditioned conjugate gradients, warm-started from the previous
step's dv. One thread per region does the whole solve in one launch: its sums run in a fixed
order, so a rerun gives the same bits on any device, and on the CPU a step is a single call.
The driven vertex is a known velocity (moved to the right-hand side); the fixed ring has dv = 0.
A spherical probe (sphere mode) constrains each surface vertex it holds along the sphere's normal:
its normal velocity is prescribed (the step ends on the sphere) and CG moves it only in the tangent
plane (Baraff & Witkin's filter, kernels/implicit/block_cg.py); a vertex is held where its predicted
position (x + dt v) is inside the sphere, or where it is on the sphere while the tissue pushes the
probe (which keeps a held vertex held: no chatter). The feedback force is the sum of the contact
reactions (kernels/probes/sphere.py), in local order.
"""

import functools

import warp as wp

from ..arrays import CGArrays, ProbeArrays, ProbeSphereArrays, TissueArrays
from ..explicit.step import advance
from ..laws import LAWS
from ..probes.press import drive_vertex
from ..probes.sphere import onto_sphere, sphere_constrain
from .block_cg import solve_block_cg

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

CONTACT_SLACK = 1.0e-5
"""A vertex within radius x (1 + this) of the centre is on the sphere (float32 positions)."""


@wp.func
def implicit_rhs(f: wp.vec3, Kv: wp.vec3, correction: wp.vec3, dt: float):
    # a row's right-hand side b = dt (f0 - dt K v0) - A_ic dv_c, from implicit_row's terms (kernels/laws)
    return dt * (f - dt * Kv) + correction


@wp.func
def implicit_update(x: wp.vec3, u: wp.vec3, dv: wp.vec3, held_normal: wp.vec3, centre: wp.vec3, radius: float, dt: float):
    # v1 = v0 + dv, x1 = x0 + dt v1 (advance); a vertex the sphere held (a nonzero normal) ends
    # exactly on the sphere (the solve held it on the tangent plane)
    x1, u1 = advance(x, u, dv, dt)
    if wp.length_sq(held_normal) > 0.0:
        x1, u1 = onto_sphere(x, x1, centre, radius, dt)
    return x1, u1


@functools.cache
def region_kernel(law: str):
    """The implicit one-region step of tissue law `law` (a key of kernels.laws.LAWS): its entries'
    arrays typed by the law; the linear system's rows are the mesh's CSR adjacency (TissueArrays)."""
    implicit_row, nodal_pressure = LAWS[law].implicit_row, LAWS[law].nodal_pressure
    TOPOLOGY, PARAMS = LAWS[law].ENTRY_TOPOLOGY, LAWS[law].ENTRY_PARAMS
    VOLUMETRIC = LAWS[law].VOLUMETRIC

    @wp.kernel(module="unique", enable_backward=False)
    def integrate_region_implicit(
        free_vertex: wp.array(dtype=wp.int32),
        free_count: int,
        vertex_count: int,
        vertex_local: wp.array(dtype=wp.int32),
        tissue: TissueArrays,
        entry_offsets: wp.array(dtype=wp.int32),
        entry_topology: TOPOLOGY,
        entry_params: PARAMS,
        pressure: wp.array(dtype=wp.float32),
        anchor_scale: float,
        probe: ProbeArrays,
        sphere: ProbeSphereArrays,
        dt: float,
        max_iterations: int,
        tolerance: float,
        q_in: wp.array(dtype=wp.vec3),
        qd_in: wp.array(dtype=wp.vec3),
        cg: CGArrays,
        q_out: wp.array(dtype=wp.vec3),
        qd_out: wp.array(dtype=wp.vec3),
    ):
        pv = probe.probe_vertex[0]
        mode = probe.probe_mode[0]
        driven = int(-1)
        dv_driven = wp.vec3(0.0)
        if mode == 1 and pv >= 0:
            driven = pv
            dv_driven = (probe.probe_target[0] - q_in[pv]) / dt - qd_in[pv]
        constrained = int(0)
        centre = probe.probe_target[0]
        radius = float(0.0)
        if mode == 3:
            constrained = 1
            radius = sphere.probe_radius[0]
        reaction = wp.vec3(0.0)

        # 0) a volumetric law's nodal pressures over the region's vertices (free and fixed ring)
        if wp.static(VOLUMETRIC):
            for i in range(vertex_count):
                v = free_vertex[i]
                pressure[v] = nodal_pressure(entry_offsets[v], entry_offsets[v + 1], entry_topology, entry_params, 0, q_in, q_in)

        # 1) forces, diagonal blocks and right-hand side b = dt (f0 - dt K v0) - A_ic dv_c
        b_norm2 = float(0.0)
        for i in range(free_count):
            v = free_vertex[i]
            x = q_in[v]
            u = qd_in[v]
            f, D, Kv, correction = implicit_row(
                x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale, tissue.particle_mass[v], dt,
                entry_offsets[v], entry_offsets[v + 1], entry_topology, entry_params, 0,
                tissue.adj_offsets[v], tissue.adj_offsets[v + 1], tissue.adj_vertex, q_in, qd_in,
                vertex_local, 0, v, driven, dv_driven, free_count, cg.csr_block, cg.csr_local, 0, pressure,
            )
            if v == pv and (mode == 1 or mode == 2):
                probe.probe_reaction[0] = f  # the feedback force: internal forces on the probe's vertex
            if v == pv and mode == 2:
                f += probe.probe_force[0]
            cg.diag[i] = D
            cg.diag_inv[i] = wp.inverse(D)
            b = implicit_rhs(f, Kv, correction, dt)
            if v == driven:
                b = wp.vec3(0.0)
            if constrained != 0:
                # a vertex the sphere holds: its normal velocity prescribed, so that the step ends on the sphere
                n_c = wp.vec3(0.0)
                contact = wp.vec3(0.0)
                if sphere.probe_surface[v] != 0:
                    n_c, dv_w, b, contact = sphere_constrain(x, u, f, b, cg.dv[i], centre, radius, CONTACT_SLACK, dt)
                    cg.dv[i] = dv_w
                    reaction += contact
                cg.normal[i] = n_c
                sphere.probe_contact[v] = contact
            cg.r[i] = b
            b_norm2 += wp.dot(b, b)

        if constrained != 0:
            probe.probe_reaction[0] = reaction  # the feedback force: the sum of the contact reactions

        # 2) and 3): r = b - A dv (warm start), then conjugate gradients (kernels/implicit/block_cg.py)
        driven_local = int(-1)
        if driven >= 0:
            driven_local = vertex_local[driven]
        iterations, r_norm2, rhs_norm2 = solve_block_cg(
            free_count, driven_local, tissue.adj_offsets, free_vertex, 1, cg.csr_local, cg.csr_block, cg.diag, cg.diag_inv,
            constrained, cg.normal, b_norm2, max_iterations, tolerance, cg.dv, cg.r, cg.p, cg.Ap,
        )

        # 4) v1 = v0 + dv, x1 = x0 + dt v1; the driven vertex goes where the probe puts it
        for i in range(free_count):
            v = free_vertex[i]
            x = q_in[v]
            if v == driven:
                xd, ud = drive_vertex(x, probe.probe_target[0], dt)
                q_out[v] = xd
                qd_out[v] = ud
            else:
                n_h = wp.vec3(0.0)
                if constrained != 0:
                    n_h = cg.normal[i]
                x1, u1 = implicit_update(x, qd_in[v], cg.dv[i], n_h, centre, radius, dt)
                q_out[v] = x1
                qd_out[v] = u1
        cg.stats[0] = float(iterations)
        cg.stats[1] = wp.sqrt(r_norm2 / wp.max(rhs_norm2, 1.0e-30))

    return integrate_region_implicit


def integrate_implicit(model, region_arrays, anchor_scale, state_in, state_out, control, dt, scratch, max_iterations, tolerance):
    """Advance the free vertices by one backward-Euler step of `dt` [s] (one launch; region_arrays:
    free_vertex, free_count, vertex_local and the region's vertex count, free and fixed ring)."""
    free_vertex, free_count, vertex_local, vertex_count = region_arrays
    wp.launch(
        region_kernel(model.law),
        dim=1,
        inputs=[
            free_vertex, free_count, vertex_count, vertex_local, model.arrays, model.entry_offsets, model.entry_topology,
            model.entry_params, model.nodal_pressure, anchor_scale, control.arrays, control.sphere_arrays, dt, max_iterations, tolerance,
            state_in.particle_q, state_in.particle_qd, scratch.arrays,
        ],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
