"""Several probes at once: the probes' vertices driven.

A region of several probes is one region grown from all their vertices (ring 0 = the seeds:
kernels/rings.py), so two regions that touch merge by being rebuilt from the union of their seeds. The solver integrates
the region's free vertices but the driven ones, which it treats like its fixed ring (known, their
velocity kept through the step); `drive_probes` then puts each driven vertex where its probe
holds it and writes the reaction, as the single-probe step does for its one probe.
"""

import warp as wp

from .forces import gather_vertex_force

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

PROBE_OFF = wp.constant(0)
PROBE_DISPLACEMENT = wp.constant(1)


@wp.kernel
def drive_probes(
    patch_probe: wp.array(dtype=wp.int32),
    probe_vertex: wp.array(dtype=wp.int32),
    probe_mode: wp.array(dtype=wp.int32),
    probe_target: wp.array(dtype=wp.vec3),
    adj_offsets: wp.array(dtype=wp.int32),
    adj_vertex: wp.array(dtype=wp.int32),
    adj_edge: wp.array(dtype=wp.int32),
    q_rest: wp.array(dtype=wp.vec3),
    anchor_ke: wp.array(dtype=wp.float32),
    anchor_kd: wp.array(dtype=wp.float32),
    spring_ke: wp.array(dtype=wp.float32),
    spring_kd: wp.array(dtype=wp.float32),
    spring_rest_length: wp.array(dtype=wp.float32),
    dt: float,
    q_in: wp.array(dtype=wp.vec3),
    qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3),
    qd_out: wp.array(dtype=wp.vec3),
    probe_reaction: wp.array(dtype=wp.vec3),
):
    p = patch_probe[wp.tid()]
    v = probe_vertex[p]
    mode = probe_mode[p]
    if mode == PROBE_OFF:
        probe_reaction[p] = wp.vec3(0.0)
        return
    # the feedback force: the tissue's internal forces on the held vertex, eqs. (3)-(6)
    x = q_in[v]
    probe_reaction[p] = gather_vertex_force(
        v, x, qd_in[v], adj_offsets, adj_vertex, adj_edge, q_rest, anchor_ke, anchor_kd, 1.0,
        spring_ke, spring_kd, spring_rest_length, q_in, qd_in,
    )
    # displacement control: the vertex is where the probe puts it
    target = probe_target[p]
    q_out[v] = target
    qd_out[v] = (target - x) / dt


def drive_probe_vertices(model, patch_probe, probes, dt, state_in, state_out):
    """Drive the probes of one region (`patch_probe`: their indices in `probes`) after its step."""
    dm = model.dmesh
    wp.launch(
        drive_probes,
        dim=patch_probe.shape[0],
        inputs=[
            patch_probe, probes.probe_vertex, probes.probe_mode, probes.probe_target, dm.adj_offsets, dm.adj_vertex,
            dm.adj_edge, model.particle_q_rest, model.anchor_ke, model.anchor_kd, model.spring_ke, model.spring_kd,
            model.spring_rest_length, dt, state_in.particle_q, state_in.particle_qd,
        ],
        outputs=[state_out.particle_q, state_out.particle_qd, probes.probe_reaction],
        device=model.device,
    )
