"""Several rigid spheres driven along a path: their contact with the region, and whether it must move.

After each integrator step, one thread goes over the region's vertices in local order: a free
surface vertex the step left inside a sphere is put on its surface (the law of
kernels/probes/sphere.py: frictionless, one-sided), and its contact reaction is summed into that
sphere's feedback force (a gather in a fixed order: the same bits every run). With the explicit
step the internal force is the step's own, f = m (v_out - v_in) / dt: the forces at its start,
where the last pass left every contact vertex on the sphere. The implicit step holds sphere 0 in its
own solve (`held`), but only the vertices its test finds in the sphere at the start of a step: those
on the trailing side of a sliding sphere are released, relax into it within the step and come back
here. Its m dv / dt is the force at that relaxed end, a third short of the static equilibrium's
(docs/stroke.md). So with `held`, a second launch reads each contact reaction from the internal force
(kernels/laws) at the end of the step, with every contact vertex on the sphere. The same pass tells
the host, per sphere, how many vertices it touches and whether it came within `guard` of a vertex
on ring `near_ring` or beyond: there the region no longer holds the contact and must be rebuilt
around it before the sphere reaches the fixed outer ring.
"""

import functools

import warp as wp

from ..arrays import struct_of
from ..implicit.step import CONTACT_SLACK
from ..laws import LAWS, pressure_pass
from .sphere import onto_sphere_from, sphere_contact_reaction, sphere_normal

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


STROKE_COUNTS = ("free_count", "vertex_count", "near_ring")
"""The entries of a stroke's counts array (int32, device): the free vertices the step moves (read by
the explicit step, kernels/explicit/step.py, as its counts[0]), the region's vertices the contact
pass goes over, the first ring whose vertices near a sphere move the region."""

HELD_SLACK = wp.constant(CONTACT_SLACK)
"""With the implicit step, a vertex within radius x (1 + this) of a centre is on the sphere (float32 positions)."""

_INT = wp.array(dtype=wp.int32)
_VEC = wp.array(dtype=wp.vec3)
_FLOAT = wp.array(dtype=wp.float32)

StrokeSpheres = struct_of(
    "StrokeSpheres",
    "The spheres of a stroke, one entry each: centre [m] in, the last frame's centre [m]; reaction [N], contact count,"
    " near-the-edge flag out.",
    {"centre": wp.array(dtype=wp.vec3), "previous": wp.array(dtype=wp.vec3), "reaction": wp.array(dtype=wp.vec3)}
    | {"touching": wp.array(dtype=wp.int32), "near_edge": wp.array(dtype=wp.int32)},
)


@wp.func
def held_centre(spheres: StrokeSpheres, p: int, alpha: float):
    # a first-order hold of sphere p across the frame's substeps: alpha = (s + 1) / n of the way from
    # the last frame's centre to this one's, so that no substep takes a whole frame's move
    c0 = spheres.previous[p]
    return c0 + alpha * (spheres.centre[p] - c0)


@functools.cache
def reactions_kernel(law: str):
    """The stroke's contact reactions at the end of an implicit step, of tissue law `law` (kernels.laws.LAWS)."""
    vertex_force, Entries, region_pressure = LAWS[law].vertex_force, LAWS[law].Entries, pressure_pass(law)

    @wp.kernel(module="unique", enable_backward=False)
    def sum_stroke_reactions(
        region_vertex: _INT, counts: _INT, vertex_local: _INT, surface: _INT, spheres: StrokeSpheres,
        probe_count: int, radius: float, entries: Entries, q_rest: _VEC,
        anchor_ke: _FLOAT, anchor_kd: _FLOAT, anchor_scale: float, q_out: _VEC, qd_out: _VEC,
    ):
        # one thread, after constrain_stroke_spheres (the implicit step): each contact's reaction from the
        # internal force at the end of the step, eqs. (3)-(6), summed in local order (a volumetric
        # law's nodal pressures first, at the end of the step)
        free_count = counts[0]
        region_pressure(region_vertex, counts[1], entries, q_out)
        for i in range(counts[1]):
            v = region_vertex[i]
            if surface[v] == 0 or vertex_local[v] >= free_count:
                continue
            x = q_out[v]
            u = qd_out[v]
            for p in range(probe_count):
                n, l = sphere_normal(x, spheres.centre[p])
                if l < radius * (1.0 + HELD_SLACK):
                    f = vertex_force(x, u, q_rest[v], anchor_ke[v], anchor_kd[v], anchor_scale,
                                     entries.offsets[v], entries.offsets[v + 1], entries.topology, entries.params, 0, q_out, qd_out,
                                     entries.pressure)
                    spheres.reaction[p] = spheres.reaction[p] + sphere_contact_reaction(f, n)

    return sum_stroke_reactions


@wp.kernel
def constrain_stroke_spheres(
    region_vertex: _INT, counts: _INT, vertex_ring: _INT, vertex_local: _INT, surface: _INT, particle_mass: wp.array(dtype=wp.float32), spheres: StrokeSpheres, probe_count: int,
    radius: float, guard: float, held: int, alpha: float, dt: float, q_in: _VEC, qd_in: _VEC, q_out: _VEC, qd_out: _VEC,
):
    for p in range(probe_count):
        spheres.reaction[p] = wp.vec3(0.0)
        spheres.touching[p] = 0
        spheres.near_edge[p] = 0
    free_count = counts[0]
    near_ring = counts[2]
    for i in range(counts[1]):
        v = region_vertex[i]
        if surface[v] == 0:
            continue
        free = vertex_local[v] < free_count
        outer = vertex_ring[v] >= near_ring
        f = wp.vec3(0.0)
        if free:
            f = particle_mass[v] * (qd_out[v] - qd_in[v]) / dt  # the internal force of the step
        for p in range(probe_count):
            c = held_centre(spheres, p, alpha)
            n, l = sphere_normal(q_out[v], c)
            if outer and l < radius + guard:
                spheres.near_edge[p] = 1
            if free and l < radius * (1.0 + float(held) * HELD_SLACK):
                x1, u1, n1 = onto_sphere_from(q_in[v], q_out[v], c, radius, dt)
                q_out[v] = x1
                qd_out[v] = u1
                spheres.touching[p] = spheres.touching[p] + 1
                if held == 0:
                    spheres.reaction[p] = spheres.reaction[p] + sphere_contact_reaction(f, n1)
    if alpha >= 1.0:
        for p in range(probe_count):
            spheres.previous[p] = spheres.centre[p]  # the frame is done: the next one starts here


def constrain_spheres(model, region_vertex, counts, vertex_ring, vertex_local, surface, spheres,
                      count, radius, guard, dt, state_in, state_out, held, anchor_scale, alpha=1.0):
    """Put the free surface vertices a step left inside the spheres (`spheres`, a StrokeSpheres of `count`)
    on their surfaces; write each sphere's reaction [N], contact count and near-the-edge flag. `counts`
    (device int32, laid out as STROKE_COUNTS, read when the launch runs, so that a
    captured launch serves every region): the region's first vertex_count vertices (`region_vertex`,
    ring of each mesh vertex `vertex_ring`) are gone over; those with `vertex_local` < free_count move,
    and one on ring near_ring or beyond that comes within `guard` of a sphere sets its flag. held=1 (the implicit step, which held
    sphere 0 in its solve): the reactions are the internal forces at the end of the step (anchors
    scaled by `anchor_scale`), read by a second launch (sum_stroke_reactions). alpha: how far the
    substep is through the frame, (s + 1) / n: the spheres stand that far from their last frame's
    centres to this one's, and alpha = 1 ends the frame.

    Arrays are direct arguments, not the structs of kernels/arrays.py: a CPU graph capture walks
    every member of a struct argument: with TissueArrays and RegionArrays here, capturing the step
    after a relocation took 410 us against 330 us (docs/performance.md). The explicit step's launch
    takes no more than it needs (a capture costs about 10 us of CPU time per argument)."""
    wp.launch(
        constrain_stroke_spheres,
        dim=1,
        inputs=[region_vertex, counts, vertex_ring, vertex_local, surface, model.particle_mass,
                spheres, count, radius, guard, int(held), float(alpha), dt, state_in.particle_q, state_in.particle_qd],
        outputs=[state_out.particle_q, state_out.particle_qd],
        device=model.device,
    )
    if held:
        dm = model.dmesh
        wp.launch(
            reactions_kernel(model.law),
            dim=1,
            inputs=[region_vertex, counts, vertex_local, surface, spheres, count, radius, model.entries,
                    dm.rest_position, model.anchor_ke, model.anchor_kd, float(anchor_scale),
                    state_out.particle_q, state_out.particle_qd],
            device=model.device,
        )
