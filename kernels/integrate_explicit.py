"""Semi-implicit (symplectic) Euler on the region's free vertices: the paper's explicit scheme.

One launch per step: gather the forces from `state_in`, integrate, write `state_out`. A
grid-stride loop over the free vertices: one thread per vertex on CUDA, a single thread on the
CPU, where each thread's prologue (copying every array descriptor) would otherwise cost more than
the vertex's physics. The probe's vertex is driven (displacement mode) or pushed (force mode), and
its thread writes the reaction, so the feedback force needs no second kernel.
"""

import warp as wp

from .arrays import ProbeArrays, TissueArrays
from .forces import add_spring_force, anchor_force

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.kernel
def integrate_region_explicit(
    free_vertex: wp.array(dtype=wp.int32),
    free_count: int,
    stride: int,
    # the CSR arrays of the inner loop as arguments of their own: on the CPU Warp compiles direct array
    # arguments for unit stride (a struct's members keep a stride read at run time), ~3% of this step
    adj_offsets: wp.array(dtype=wp.int32),
    adj_vertex: wp.array(dtype=wp.int32),
    adj_spring: wp.array(dtype=wp.vec3),
    tissue: TissueArrays,
    anchor_scale: float,
    probe: ProbeArrays,
    dt: float,
    q_in: wp.array(dtype=wp.vec3),
    qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3),
    qd_out: wp.array(dtype=wp.vec3),
):
    # the gather written out in the kernel (a wp.func taking the arrays would copy every descriptor a call)
    pv = probe.probe_vertex[0]
    mode = probe.probe_mode[0]
    for i in range(wp.tid(), free_count, stride):
        v = free_vertex[i]
        x = q_in[v]
        u = qd_in[v]
        f = anchor_force(x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale)
        for k in range(adj_offsets[v], adj_offsets[v + 1]):
            j = adj_vertex[k]
            spring = adj_spring[k]  # (k_ij, d_ij, rest length)
            f = add_spring_force(f, x, u, q_in[j], qd_in[j], spring[0], spring[1], spring[2])
        if v == pv and mode != 0:
            probe.probe_reaction[0] = f  # the feedback force: the tissue's internal forces on the probe
        if v == pv and mode == 1:
            # displacement control: the vertex is where the probe puts it
            target = probe.probe_target[0]
            q_out[v] = target
            qd_out[v] = (target - x) / dt
        else:
            if v == pv and mode == 2:
                f += probe.probe_force[0]
            # m u'' + d u' + k u = F, eq. (3), by semi-implicit Euler: velocity first, then position
            u1 = u + dt * f / tissue.particle_mass[v]
            q_out[v] = x + dt * u1
            qd_out[v] = u1


def integrate_explicit(model, free_vertex, free_count, anchor_scale, state_in, state_out, control, dt):
    """Advance the free vertices by one semi-implicit Euler step of `dt` [s]."""
    threads = 1 if model.device.is_cpu else free_count
    wp.launch(
        integrate_region_explicit,
        dim=threads,
        inputs=[free_vertex, free_count, threads, model.dmesh.adj_offsets, model.dmesh.adj_vertex, model.adj_spring, model.arrays, anchor_scale, control.arrays, dt, state_in.particle_q, state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
