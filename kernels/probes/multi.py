"""Several probes at once: the probes' vertices driven.

A region of several probes is one region grown from all their vertices (ring 0 = the seeds:
kernels/region/rings.py), so two regions that touch merge by being rebuilt from the union of their seeds. The solver integrates
the region's free vertices but the driven ones, which it treats like its fixed ring (known, their
velocity kept through the step); `drive_probes` then puts each driven vertex where its probe
holds it and writes the reaction, as the single-probe step does for its one probe.
"""

import functools

import warp as wp

from ..arrays import ProbeArrays, TissueArrays
from ..laws import LAWS
from .press import drive_vertex

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

PROBE_OFF = wp.constant(0)
PROBE_DISPLACEMENT = wp.constant(1)


@functools.cache
def drive_kernel(law: str):
    """The multi-probe drive of tissue law `law` (a key of kernels.laws.LAWS)."""
    vertex_force, Entries = LAWS[law].vertex_force, LAWS[law].Entries

    @wp.kernel(module="unique", enable_backward=False)
    def drive_probes(
        patch_probe: wp.array(dtype=wp.int32), probes: ProbeArrays, tissue: TissueArrays, entries: Entries, dt: float,
        q_in: wp.array(dtype=wp.vec3), qd_in: wp.array(dtype=wp.vec3),
        q_out: wp.array(dtype=wp.vec3), qd_out: wp.array(dtype=wp.vec3),
    ):
        p = patch_probe[wp.tid()]
        v = probes.probe_vertex[p]
        mode = probes.probe_mode[p]
        if mode == PROBE_OFF:
            probes.probe_reaction[p] = wp.vec3(0.0)
            return
        # the feedback force: the tissue's internal forces on the held vertex, eqs. (3)-(6) (a volumetric
        # law's nodal pressures as its region's step just left them, at q_in)
        x = q_in[v]
        probes.probe_reaction[p] = vertex_force(x, qd_in[v], tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], 1.0,
                                                entries.offsets[v], entries.offsets[v + 1], entries.topology, entries.params, 0, q_in, qd_in,
                                                entries.pressure)
        # displacement control: the vertex is where the probe puts it
        xd, ud = drive_vertex(x, probes.probe_target[p], dt)
        q_out[v] = xd
        qd_out[v] = ud

    return drive_probes


def drive_probe_vertices(model, patch_probe, probes, dt, state_in, state_out):
    """Drive the probes of one region (`patch_probe`: their indices in `probes`) after its step."""
    wp.launch(
        drive_kernel(model.law),
        dim=patch_probe.shape[0],
        inputs=[patch_probe, probes.arrays, model.arrays, model.entries, dt, state_in.particle_q, state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
