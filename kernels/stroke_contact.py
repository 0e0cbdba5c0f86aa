"""Several rigid spheres driven along a path: their contact with the region, and whether it must move.

After each integrator step, one thread goes over the region's vertices in local order: a free
surface vertex the step left inside a sphere is put on its surface (the law of
kernels/probe_contact.py: frictionless, one-sided), and its contact reaction is summed into that
sphere's feedback force (a gather in a fixed order: the same bits every run). The same pass tells
the host, per sphere, how many vertices it touches and whether it came within `guard` of a vertex
on ring `near_ring` or beyond: there the region no longer holds the contact and must be rebuilt
around it before the sphere reaches the fixed outer ring.
"""

import warp as wp

from .arrays import RegionArrays, TissueArrays, struct_of
from .probe_contact import sphere_contact_reaction, sphere_normal

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


StrokeSpheres = struct_of(
    "StrokeSpheres",
    "The spheres of a stroke, one entry each: centre [m] in; reaction [N], contact count, near-the-edge flag out.",
    {"centre": wp.array(dtype=wp.vec3), "reaction": wp.array(dtype=wp.vec3)}
    | {"touching": wp.array(dtype=wp.int32), "near_edge": wp.array(dtype=wp.int32)},
)


@wp.kernel
def constrain_stroke_spheres(
    region: RegionArrays, vertex_count: int, vertex_local: wp.array(dtype=wp.int32), free_count: int, near_ring: int,
    surface: wp.array(dtype=wp.int32), tissue: TissueArrays, spheres: StrokeSpheres, probe_count: int,
    radius: float, guard: float, dt: float,
    q_in: wp.array(dtype=wp.vec3), qd_in: wp.array(dtype=wp.vec3), q_out: wp.array(dtype=wp.vec3), qd_out: wp.array(dtype=wp.vec3),
):
    for p in range(probe_count):
        spheres.reaction[p] = wp.vec3(0.0)
        spheres.touching[p] = 0
        spheres.near_edge[p] = 0
    for i in range(vertex_count):
        v = region.region_vertex[i]
        if surface[v] == 0:
            continue
        free = vertex_local[v] < free_count
        outer = region.vertex_ring[v] >= near_ring
        f = wp.vec3(0.0)
        if free:
            f = tissue.particle_mass[v] * (qd_out[v] - qd_in[v]) / dt  # the internal force of the step
        for p in range(probe_count):
            c = spheres.centre[p]
            n, l = sphere_normal(q_out[v], c)
            if outer and l < radius + guard:
                spheres.near_edge[p] = 1
            if free and l < radius:
                x1 = c + radius * n
                q_out[v] = x1
                qd_out[v] = (x1 - q_in[v]) / dt
                spheres.reaction[p] = spheres.reaction[p] + sphere_contact_reaction(f, n)
                spheres.touching[p] = spheres.touching[p] + 1


def constrain_spheres(model, region_arrays, vertex_count, vertex_local, free_count, near_ring, surface, spheres, count,
                      radius, guard, dt, state_in, state_out):
    """Put the free surface vertices a step left inside the spheres (`spheres`, a StrokeSpheres of `count`)
    on their surfaces; write each sphere's reaction [N], contact count and near-the-edge flag.
    `region_arrays`: the region's RegionArrays (its first `vertex_count` vertices are gone over)."""
    wp.launch(
        constrain_stroke_spheres,
        dim=1,
        inputs=[region_arrays, vertex_count, vertex_local, free_count, near_ring, surface, model.arrays, spheres, count,
                radius, guard, dt, state_in.particle_q, state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
