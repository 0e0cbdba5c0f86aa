"""Implicit (backward) Euler on the region's free vertices, with a matrix-free CG solve.

Linearized once per step (Baraff & Witkin): (M + dt C + dt^2 K) dv = dt (f0 - dt K v0), with
K = -df/dx (spring blocks made positive semi-definite where a spring is compressed) and
C = -df/dv. Block-Jacobi preconditioned conjugate gradients, warm-started from the previous
step's dv. One thread per region does the whole solve in one launch: its sums run in a fixed
order, so a rerun gives the same bits on any device, and on the CPU a step is a single call.
The driven vertex is a known velocity (moved to the right-hand side); the fixed ring has dv = 0.
A spherical probe (sphere mode) constrains each surface vertex it holds along the sphere's normal:
its normal velocity is prescribed (the step ends on the sphere) and CG moves it only in the tangent
plane (Baraff & Witkin's filter, kernels/block_cg.py); a vertex is held where its predicted
position (x + dt v) is inside the sphere, or where it is on the sphere while the tissue pushes the
probe (which keeps a held vertex held: no chatter). The feedback force is the sum of the contact
reactions (kernels/probe_contact.py), in local order.
"""

import warp as wp

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

from .arrays import CGArrays, ProbeArrays, ProbeSphereArrays, TissueArrays
from .block_cg import solve_block_cg
from .forces import add_spring_force, anchor_force, spring_block
from .probe_contact import onto_sphere, sphere_constrain

CONTACT_SLACK = 1.0e-5
"""A vertex within radius x (1 + this) of the centre is on the sphere (float32 positions)."""


@wp.kernel
def integrate_region_implicit(
    free_vertex: wp.array(dtype=wp.int32),
    free_count: int,
    vertex_local: wp.array(dtype=wp.int32),
    tissue: TissueArrays,
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

    # 1) forces, diagonal blocks and right-hand side b = dt (f0 - dt K v0) - A_ic dv_c
    b_norm2 = float(0.0)
    for i in range(free_count):
        v = free_vertex[i]
        x = q_in[v]
        u = qd_in[v]
        # anchor spring and damper, eq. (3); springs and dampers along the edges below, eqs. (4)-(6)
        f = anchor_force(x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale)
        ka = anchor_scale * tissue.anchor_ke[v]
        kda = anchor_scale * tissue.anchor_kd[v]
        D = (tissue.particle_mass[v] + dt * kda + dt * dt * ka) * wp.identity(n=3, dtype=float)
        Kv = ka * u
        correction = wp.vec3(0.0)
        for k in range(tissue.adj_offsets[v], tissue.adj_offsets[v + 1]):
            j = tissue.adj_vertex[k]
            spring = tissue.adj_spring[k]  # (k_ij, d_ij, rest length)
            f = add_spring_force(f, x, u, q_in[j], qd_in[j], spring[0], spring[1], spring[2])
            B, Kb = spring_block(spring[0], spring[1], spring[2], q_in[j] - x, dt)
            cg.csr_block[k] = B
            # the neighbour's local index where it is an unknown of the solve (free, not driven), else -1
            lj = vertex_local[j]
            if lj >= free_count or j == driven or v == driven:
                lj = -1
            cg.csr_local[k] = lj
            D += B
            Kv += Kb * (u - qd_in[j])
            if j == driven:
                correction += B * dv_driven  # -A_ic dv_c, with A_ic = -B
        if v == pv and (mode == 1 or mode == 2):
            probe.probe_reaction[0] = f  # the feedback force: internal forces on the probe's vertex
        if v == pv and mode == 2:
            f += probe.probe_force[0]
        cg.diag[i] = D
        cg.diag_inv[i] = wp.inverse(D)
        b = dt * (f - dt * Kv) + correction
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

    # 2) and 3): r = b - A dv (warm start), then conjugate gradients (kernels/block_cg.py)
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
            target = probe.probe_target[0]
            q_out[v] = target
            qd_out[v] = (target - x) / dt
        else:
            u1 = qd_in[v] + cg.dv[i]
            x1 = x + dt * u1
            if constrained != 0:
                if wp.length_sq(cg.normal[i]) > 0.0:
                    # exactly on the sphere (the solve held it on the tangent plane)
                    x1, u1 = onto_sphere(x, x1, centre, radius, dt)
            q_out[v] = x1
            qd_out[v] = u1
    cg.stats[0] = float(iterations)
    cg.stats[1] = wp.sqrt(r_norm2 / wp.max(rhs_norm2, 1.0e-30))


def integrate_implicit(model, region_arrays, anchor_scale, state_in, state_out, control, dt, scratch, max_iterations, tolerance):
    """Advance the free vertices by one backward-Euler step of `dt` [s] (one launch)."""
    free_vertex, free_count, vertex_local = region_arrays
    wp.launch(
        integrate_region_implicit,
        dim=1,
        inputs=[
            free_vertex, free_count, vertex_local, model.arrays, anchor_scale, control.arrays, control.sphere_arrays, dt, max_iterations, tolerance,
            state_in.particle_q, state_in.particle_qd, scratch.arrays,
        ],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
