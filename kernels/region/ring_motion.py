"""How far each ring of a region has moved, and how far its fixed ring would move if freed.

The adaptive region (almsdm_warp.protocol.adaptive) checks these every few steps instead of the whole
state: one launch and a read-back of a few floats. One thread walks the region (a few hundred
vertices at most between checks), so the maxima need no atomics and the launch no clearing.
"""

import functools

import warp as wp

from ..arrays import RegionArrays, TissueArrays
from ..laws import LAWS, pressure_pass

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@functools.cache
def motion_kernel(law: str):
    """The ring-motion check of tissue law `law` (a key of kernels.laws.LAWS)."""
    static_row, Entries, region_pressure = LAWS[law].static_row, LAWS[law].Entries, pressure_pass(law)

    @wp.kernel(module="unique", enable_backward=False)
    def eval_ring_motion(
        region: RegionArrays, count: int, slots: int, tissue: TissueArrays, entries: Entries, q: wp.array(dtype=wp.vec3),
        motion: wp.array(dtype=wp.float32)
    ):
        # motion[0]: the largest displacement a fixed-ring vertex would take if it alone were freed;
        # motion[1 + r]: the largest displacement |q - q_rest| on ring r (free rings; 0 on the fixed one);
        # motion[slots - 1]: sum over the fixed ring of f . u_J, the energy the fixed ring's reactions
        # would release if its vertices were freed one by one (twice that energy)
        for s in range(slots):
            motion[s] = 0.0
        energy = float(0.0)
        region_pressure(region.region_vertex, count, entries, q)  # a tet law's nodal pressures at q (outside the region 0: at rest)
        for i in range(count):
            v = region.region_vertex[i]
            x = q[v]
            if region.region_boundary[i] == 0:
                slot = wp.min(1 + region.region_ring[i], slots - 2)  # rings past the array share its last ring entry
                motion[slot] = wp.max(motion[slot], wp.length(x - tissue.q_rest[v]))
            else:
                # one Jacobi step of the static equilibrium K u = f at v: anchor and springs, eqs. (3)-(5),
                # linearized at the current state, with v's neighbours held where they are
                # (a static equilibrium: velocities zero, so the dampers add nothing)
                f, D = static_row(x, tissue.q_rest[v], tissue.anchor_ke[v], entries.offsets[v], entries.offsets[v + 1],
                                  entries.topology, entries.params, 0, q, entries.pressure)
                if wp.determinant(D) > 0.0:
                    u_J = wp.inverse(D) * f
                    motion[0] = wp.max(motion[0], wp.length(u_J))
                    energy += wp.dot(f, u_J)
        motion[slots - 1] = energy

    return eval_ring_motion


def eval_region_motion(model, region, state, motion):
    """Fill `motion` (float32, >= rings + 3 entries) for `region` at `state`: see eval_ring_motion."""
    wp.launch(
        motion_kernel(model.law),
        dim=1,
        inputs=[region.arrays, region.vertex_count, motion.shape[0], model.arrays, model.entries, state.particle_q],
        outputs=[motion],
        device=model.device,
    )
