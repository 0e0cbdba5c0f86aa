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

from .arrays import struct_of
from .probe_contact import sphere_contact_reaction, sphere_normal

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


_INT = wp.array(dtype=wp.int32)
_VEC = wp.array(dtype=wp.vec3)

StrokeSpheres = struct_of(
    "StrokeSpheres",
    "The spheres of a stroke, one entry each: centre [m] in; reaction [N], contact count, near-the-edge flag out.",
    {"centre": wp.array(dtype=wp.vec3), "reaction": wp.array(dtype=wp.vec3)}
    | {"touching": wp.array(dtype=wp.int32), "near_edge": wp.array(dtype=wp.int32)},
)


@wp.kernel
def constrain_stroke_spheres(
    region_vertex: _INT, vertex_count: int, vertex_ring: _INT, near_ring: int, vertex_local: _INT, free_count: int,
    surface: _INT, particle_mass: wp.array(dtype=wp.float32), spheres: StrokeSpheres, probe_count: int,
    radius: float, guard: float, dt: float, q_in: _VEC, qd_in: _VEC, q_out: _VEC, qd_out: _VEC,
):
    for p in range(probe_count):
        spheres.reaction[p] = wp.vec3(0.0)
        spheres.touching[p] = 0
        spheres.near_edge[p] = 0
    for i in range(vertex_count):
        v = region_vertex[i]
        if surface[v] == 0:
            continue
        free = vertex_local[v] < free_count
        outer = vertex_ring[v] >= near_ring
        f = wp.vec3(0.0)
        if free:
            f = particle_mass[v] * (qd_out[v] - qd_in[v]) / dt  # the internal force of the step
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


def constrain_spheres(model, region_vertex, vertex_count, vertex_ring, near_ring, vertex_local, free_count, surface, spheres,
                      count, radius, guard, dt, state_in, state_out):
    """Put the free surface vertices a step left inside the spheres (`spheres`, a StrokeSpheres of `count`)
    on their surfaces; write each sphere's reaction [N], contact count and near-the-edge flag. The
    region's first `vertex_count` vertices (`region_vertex`, ring of each mesh vertex `vertex_ring`) are
    gone over; those with `vertex_local` < `free_count` move.

    Arrays are direct arguments, not the structs of kernels/arrays.py: a CPU graph capture walks
    every member of a struct argument: with TissueArrays and RegionArrays here, capturing the step
    after a relocation took 410 us against 330 us (docs/performance.md)."""
    wp.launch(
        constrain_stroke_spheres,
        dim=1,
        inputs=[region_vertex, vertex_count, vertex_ring, near_ring, vertex_local, free_count, surface, model.particle_mass,
                spheres, count, radius, guard, dt, state_in.particle_q, state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
