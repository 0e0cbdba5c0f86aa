"""A batch of presses, implicit (backward) Euler: one thread per palpation, one step per launch.

The one-palpation implicit step (kernels/integrate_implicit.py) on each palpation's compacted region:
linearized once per step (Baraff & Witkin), (M + dt C + dt^2 K) dv = dt (f0 - dt K v0),
block-Jacobi preconditioned conjugate gradients warm-started from the palpation's previous dv;
the driven vertex (local 0 while the probe presses) is a known velocity, the fixed ring has
dv = 0. A sphere (BatchSphere, radius > 0) drives no vertex: it holds each free surface vertex
it contains along its normal, as the one-palpation step does (kernels/probe_contact.py), and the
feedback force is the sum of the contact reactions. The same expressions and the same order of every sum (vertices in local order, each
vertex's springs in mesh CSR order), so a palpation of the batch gives the same bits as
``Palpation(..., integrator="implicit").press`` on the CPU.
"""

import warp as wp

from .arrays import BatchCGArrays, BatchPress, BatchRegionArrays, BatchSphere, TissueArrays
from .block_cg import solve_block_cg
from .forces import add_spring_force, anchor_force, spring_block
from .integrate_implicit import CONTACT_SLACK
from .probe_contact import onto_sphere, sphere_constrain

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def record_force(press: BatchPress, b: int, step: int, f: wp.vec3):
    # palpation b's feedback force at `step`: its largest magnitude (float64, as the host takes it) and the hold's
    fx = wp.float64(f[0])
    fy = wp.float64(f[1])
    fz = wp.float64(f[2])
    mag = wp.sqrt(fx * fx + fy * fy + fz * fz)
    if mag > press.peak_force[b]:
        press.peak_force[b] = mag
        press.peak_reaction[b] = f
    if step == press.press_steps - 1:
        press.hold_reaction[b] = f


@wp.kernel
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
        # the probe's target, in float64 as the host computes it, then float32; local vertex 0 is driven
        frac = wp.min(wp.float64(step + 1) / wp.float64(press.ramp_steps), wp.float64(1.0))
        if probe.radius > 0.0:
            # the sphere's centre: touching the surface at the contact vertex at rest, then along the press
            direction = press.press_direction[b]
            start = wp.vec3d(tissue.q_rest[regions.region_vertex[b, probe.contact_local[b]]]) - direction * probe.radius64
            target = wp.vec3(start + direction * press.depth * frac)
            constrained = 1
        else:
            target = wp.vec3(wp.vec3d(tissue.q_rest[regions.region_vertex[b, 0]]) + press.press_direction[b] * press.depth * frac)
            driven = 0
            dv_driven = (target - q_in[b, 0]) / dt - qd_in[b, 0]

    # 1) forces, diagonal blocks and right-hand side b = dt (f0 - dt K v0) - A_ic dv_c
    b_norm2 = float(0.0)
    for i in range(free_n):
        v = regions.region_vertex[b, i]
        x = q_in[b, i]
        u = qd_in[b, i]
        # anchor spring and damper, eq. (3); springs and dampers along the edges below, eqs. (4)-(6)
        f = anchor_force(x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale)
        ka = anchor_scale * tissue.anchor_ke[v]
        kda = anchor_scale * tissue.anchor_kd[v]
        D = (tissue.particle_mass[v] + dt * kda + dt * dt * ka) * wp.identity(n=3, dtype=float)
        Kv = ka * u
        correction = wp.vec3(0.0)
        for k in range(regions.local_offsets[b, i], regions.local_offsets[b, i + 1]):
            j = regions.local_neighbour[b, k]
            e = regions.local_edge[b, k]
            f = add_spring_force(f, x, u, q_in[b, j], qd_in[b, j], tissue.spring_ke[e], tissue.spring_kd[e], tissue.spring_rest_length[e])
            B, Kb = spring_block(tissue.spring_ke[e], tissue.spring_kd[e], tissue.spring_rest_length[e], q_in[b, j] - x, dt)
            cg.csr_block[b, k] = B
            # the neighbour's local index where it is an unknown of the solve (free, not driven), else -1
            lj = j
            if lj >= free_n or j == driven or i == driven:
                lj = -1
            cg.csr_local[b, k] = lj
            D += B
            Kv += Kb * (u - qd_in[b, j])
            if j == driven:
                correction += B * dv_driven  # -A_ic dv_c, with A_ic = -B
        if i == 0 and driven == 0:
            record_force(press, b, step, f)  # the feedback force: internal forces on the probe's vertex
        cg.diag[b, i] = D
        cg.diag_inv[b, i] = wp.inverse(D)
        rhs = dt * (f - dt * Kv) + correction
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

    # 2) and 3): r = b - A dv (warm start), then conjugate gradients (kernels/block_cg.py), on this palpation's rows
    solve_block_cg(
        free_n, driven, regions.local_offsets[b], regions.local_offsets[b], 0, cg.csr_local[b], cg.csr_block[b], cg.diag[b], cg.diag_inv[b],
        constrained, cg.normal[b], b_norm2, max_iterations, tolerance, cg.dv[b], cg.r[b], cg.p[b], cg.Ap[b],
    )

    if constrained != 0:
        record_force(press, b, step, reaction)  # the feedback force: the sum of the contact reactions

    # 4) v1 = v0 + dv, x1 = x0 + dt v1; the driven vertex goes where the probe puts it
    for i in range(free_n):
        x = q_in[b, i]
        if i == driven:
            q_out[b, i] = target
            qd_out[b, i] = (target - x) / dt
        else:
            u1 = qd_in[b, i] + cg.dv[b, i]
            x1 = x + dt * u1
            if constrained != 0:
                if wp.length_sq(cg.normal[b, i]) > 0.0:
                    # exactly on the sphere (the solve held it on the tangent plane)
                    x1, u1 = onto_sphere(x, x1, target, probe.radius, dt)
            q_out[b, i] = x1
            qd_out[b, i] = u1


def step_batch(batch, step, state_in, state_out, scratch, max_iterations, tolerance):
    """One implicit step of every palpation of `batch`: state_in -> state_out, (q, qd) pairs."""
    m, r, p = batch.model, batch.regions, batch
    wp.launch(
        step_batch_implicit,
        dim=p.batch_size,
        inputs=[
            r.arrays, m.arrays, 1.0, p.press_arrays, p.sphere_arrays, int(step), int(max_iterations), float(tolerance),
            state_in[0], state_in[1], scratch.arrays,
        ],
        outputs=[state_out[0], state_out[1]],
        device=m.device,
    )
