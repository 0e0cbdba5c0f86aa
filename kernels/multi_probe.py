"""Several probes at once: the probes' vertices driven.

A region of several probes is one region grown from all their vertices (ring 0 = the seeds:
kernels/rings.py), so two regions that touch merge by being rebuilt from the union of their seeds. The solver integrates
the region's free vertices but the driven ones, which it treats like its fixed ring (known, their
velocity kept through the step); `drive_probes` then puts each driven vertex where its probe
holds it and writes the reaction, as the single-probe step does for its one probe.
"""

import warp as wp

from .arrays import ProbeArrays, TissueArrays
from .forces import gather_vertex_force

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

PROBE_OFF = wp.constant(0)
PROBE_DISPLACEMENT = wp.constant(1)


@wp.kernel
def drive_probes(
    patch_probe: wp.array(dtype=wp.int32), probes: ProbeArrays, tissue: TissueArrays, dt: float,
    q_in: wp.array(dtype=wp.vec3), qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3), qd_out: wp.array(dtype=wp.vec3),
):
    p = patch_probe[wp.tid()]
    v = probes.probe_vertex[p]
    mode = probes.probe_mode[p]
    if mode == PROBE_OFF:
        probes.probe_reaction[p] = wp.vec3(0.0)
        return
    # the feedback force: the tissue's internal forces on the held vertex, eqs. (3)-(6)
    x = q_in[v]
    probes.probe_reaction[p] = gather_vertex_force(v, x, qd_in[v], tissue, 1.0, q_in, qd_in)
    # displacement control: the vertex is where the probe puts it
    target = probes.probe_target[p]
    q_out[v] = target
    qd_out[v] = (target - x) / dt


def drive_probe_vertices(model, patch_probe, probes, dt, state_in, state_out):
    """Drive the probes of one region (`patch_probe`: their indices in `probes`) after its step."""
    wp.launch(
        drive_probes,
        dim=patch_probe.shape[0],
        inputs=[patch_probe, probes.arrays, model.arrays, dt, state_in.particle_q, state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
