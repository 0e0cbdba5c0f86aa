"""Region bookkeeping on the state: when the region moves, what it leaves goes back to rest."""

import warp as wp

from ..arrays import RegionArrays, TissueArrays

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.kernel
def reset_left_behind(
    old_vertex: wp.array(dtype=wp.int32), region: RegionArrays, free_count: int, tissue: TissueArrays,
    q: wp.array(dtype=wp.vec3), qd: wp.array(dtype=wp.vec3), pressure: wp.array(dtype=wp.float32), volumetric: int,
):
    # a vertex of the old region that the new one does not integrate: at rest (a volumetric law's
    # nodal pressure 0, at rest too, until a pass of the new region's computes it)
    v = old_vertex[wp.tid()]
    lv = region.vertex_local[v]
    if lv < 0 or lv >= free_count:
        q[v] = tissue.q_rest[v]
        qd[v] = wp.vec3(0.0)
        if volumetric != 0:
            pressure[v] = 0.0


def reset_vertices_left_behind(model, old_vertex, old_count, region, states):
    """Put the old region's vertices that are not free in `region` back at rest in both `states`."""
    if old_count == 0:
        return
    for state in states:
        wp.launch(
            reset_left_behind,
            dim=old_count,
            inputs=[old_vertex, region.arrays, region.free_count, model.arrays, state.particle_q, state.particle_qd,
                    model.nodal_pressure, int(model.law_entry.volumetric)],
            device=model.device,
        )


def clear_region(model, region, states):
    """Empty `region` (Region.clear) and put the vertices it held back at rest in both `states`."""
    count = region.vertex_count
    if count:
        old = wp.clone(region.region_vertex[:count])
        region.clear()
        reset_vertices_left_behind(model, old, count, region, states)
