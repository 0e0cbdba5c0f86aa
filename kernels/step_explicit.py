"""Semi-implicit (symplectic) Euler on the region's free vertices: the paper's explicit scheme.

One launch per step, one thread per free vertex: gather the forces from `state_in`, integrate,
write `state_out`. The probe's vertex is driven (displacement mode) or pushed (force mode), and
its thread writes the reaction, so the feedback force needs no second kernel.
"""

import warp as wp

from .forces import gather_vertex_force


@wp.kernel
def integrate_region_explicit(
    free_vertex: wp.array(dtype=wp.int32),
    adj_offsets: wp.array(dtype=wp.int32),
    adj_vertex: wp.array(dtype=wp.int32),
    adj_edge: wp.array(dtype=wp.int32),
    q_rest: wp.array(dtype=wp.vec3),
    particle_mass: wp.array(dtype=wp.float32),
    anchor_ke: wp.array(dtype=wp.float32),
    anchor_kd: wp.array(dtype=wp.float32),
    anchor_scale: float,
    spring_ke: wp.array(dtype=wp.float32),
    spring_kd: wp.array(dtype=wp.float32),
    spring_rest_length: wp.array(dtype=wp.float32),
    probe_vertex: wp.array(dtype=wp.int32),
    probe_mode: wp.array(dtype=wp.int32),
    probe_target: wp.array(dtype=wp.vec3),
    probe_force: wp.array(dtype=wp.vec3),
    dt: float,
    q_in: wp.array(dtype=wp.vec3),
    qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3),
    qd_out: wp.array(dtype=wp.vec3),
    probe_reaction: wp.array(dtype=wp.vec3),
):
    v = free_vertex[wp.tid()]
    x = q_in[v]
    u = qd_in[v]
    f = gather_vertex_force(
        v, x, u, adj_offsets, adj_vertex, adj_edge, q_rest, anchor_ke, anchor_kd, anchor_scale,
        spring_ke, spring_kd, spring_rest_length, q_in, qd_in,
    )
    if v == probe_vertex[0]:
        mode = probe_mode[0]
        if mode != 0:
            probe_reaction[0] = f  # the feedback force: the tissue's internal forces on the probe
        if mode == 1:
            # displacement control: the vertex is where the probe puts it
            target = probe_target[0]
            q_out[v] = target
            qd_out[v] = (target - x) / dt
            return
        if mode == 2:
            f += probe_force[0]
    # m u'' + d u' + k u = F, eq. (3), by semi-implicit Euler: velocity first, then position
    u1 = u + dt * f / particle_mass[v]
    q_out[v] = x + dt * u1
    qd_out[v] = u1


def integrate_explicit(model, free_vertex, free_count, anchor_scale, state_in, state_out, control, dt):
    """Advance the free vertices by one semi-implicit Euler step of `dt` [s]."""
    dm = model.dmesh
    wp.launch(
        integrate_region_explicit,
        dim=free_count,
        inputs=[
            free_vertex, dm.adj_offsets, dm.adj_vertex, dm.adj_edge, model.particle_q_rest, model.particle_mass,
            model.anchor_ke, model.anchor_kd, anchor_scale, model.spring_ke, model.spring_kd, model.spring_rest_length,
            control.probe_vertex, control.probe_mode, control.probe_target, control.probe_force, dt,
            state_in.particle_q, state_in.particle_qd,
        ],
        outputs=[state_out.particle_q, state_out.particle_qd, control.probe_reaction],
        device=model.device,
    )
