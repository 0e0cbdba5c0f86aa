"""Semi-implicit (symplectic) Euler on one region's free vertices: the paper's explicit scheme.

`advance` is the update, once, for every explicit kernel (one region here, a batch in batch.py and
batch_fast.py) and for the implicit ones (kernels/implicit): velocity first, then position.

The one-region step is one launch: gather each free vertex's force from `state_in` (its law's
`vertex_force`, kernels/laws), integrate, write `state_out`; a volumetric law's nodal pressures are
a launch before it (`pressure_kernel`: over the region's vertices, counts[1] of them, free and
fixed ring, whose pressures the free vertices' tets read). A grid-stride loop over the free
vertices: one thread per vertex on CUDA, a single thread on the CPU, where each thread's prologue
(copying every array descriptor) would otherwise cost more than the vertex's physics. The free
count is read from a device array (`counts[0]`), so that a graph captured once serves every region
of a moving probe (almsdm_warp.protocol.stroke). The probe's vertex is driven (displacement mode) or
pushed (force mode), and its thread writes the reaction, so the feedback force needs no second kernel.

A spherical probe (sphere mode) is a second launch, made only for a Control with a sphere, so the
paper's probe runs the step as it was: one thread goes over the free vertices in local order,
puts each surface vertex that the step left inside the sphere on its surface (kernels/probes/sphere.py)
and sums the contact reactions (a gather in a fixed order: the same bits every run).

Its arrays are direct arguments, not the structs of kernels/arrays.py that the other kernels
take: on the CPU a struct's members cost this step 3.7% (docs/performance.md).
"""

import functools

import warp as wp

from ..arrays import ProbeArrays, ProbeSphereArrays
from ..laws import LAWS
from ..laws.tets import gathered_force
from ..probes.press import drive_vertex
from ..probes.sphere import sphere_contact_step

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def advance(x: wp.vec3, u: wp.vec3, dv: wp.vec3, dt: float):
    # m u'' + d u' + k u = F, eq. (3), by semi-implicit Euler: the velocity change dv first, then the
    # position at the new velocity; returns (position, velocity)
    u1 = u + dv
    return x + dt * u1, u1


@functools.cache
def pressure_kernel(law: str):
    """The nodal pressure pass of volumetric law `law` (its `nodal_pressure`, kernels/laws) over the
    first counts[1] vertices of a region (free and fixed ring), grid-stride as the step."""
    nodal_pressure = LAWS[law].nodal_pressure
    TOPOLOGY, PARAMS = LAWS[law].ENTRY_TOPOLOGY, LAWS[law].ENTRY_PARAMS

    @wp.kernel(module="unique", enable_backward=False)
    def eval_nodal_pressure(
        region_vertex: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32), stride: int,
        entry_offsets: wp.array(dtype=wp.int32), entry_topology: TOPOLOGY, entry_params: PARAMS,
        q: wp.array(dtype=wp.vec3), pressure: wp.array(dtype=wp.float32),
    ):
        for i in range(wp.tid(), counts[1], stride):
            v = region_vertex[i]
            pressure[v] = nodal_pressure(entry_offsets[v], entry_offsets[v + 1], entry_topology, entry_params, 0, q, q)

    return eval_nodal_pressure


def update_pressure(model, region_vertex, counts, threads, q) -> None:
    """A volumetric law's nodal pressures (model.nodal_pressure) of the first counts[1] vertices of
    `region_vertex` at positions `q` (nothing for springs)."""
    if model.law_entry.volumetric:
        wp.launch(pressure_kernel(model.law), dim=threads,
                  inputs=[region_vertex, counts, threads, model.entry_offsets, model.entry_topology, model.entry_params, q],
                  outputs=[model.nodal_pressure], device=model.device)


@functools.cache
def region_kernel(law: str, per_tet: bool = False):
    """The explicit one-region step of tissue law `law` (a key of kernels.laws.LAWS): its entries'
    arrays are typed by the law (ENTRY_TOPOLOGY, ENTRY_PARAMS). per_tet (a tet law): each free vertex
    sums its tets' forces computed once a tet (gathered_force; the entries' arrays are then each
    entry's place in the region's tet forces and those forces: kernels/region/volumes.py)."""
    if per_tet:
        vertex_force, TOPOLOGY, PARAMS = gathered_force, wp.array(dtype=wp.int32), wp.array(dtype=wp.vec3)
    else:
        vertex_force = LAWS[law].vertex_force
        TOPOLOGY, PARAMS = LAWS[law].ENTRY_TOPOLOGY, LAWS[law].ENTRY_PARAMS

    @wp.kernel(module="unique", enable_backward=False)
    def integrate_region_explicit(
        free_vertex: wp.array(dtype=wp.int32),
        counts: wp.array(dtype=wp.int32),
        stride: int,
        entry_offsets: wp.array(dtype=wp.int32),
        entry_topology: TOPOLOGY,
        entry_params: PARAMS,
        pressure: wp.array(dtype=wp.float32),
        q_rest: wp.array(dtype=wp.vec3),
        particle_mass: wp.array(dtype=wp.float32),
        anchor_ke: wp.array(dtype=wp.float32),
        anchor_kd: wp.array(dtype=wp.float32),
        anchor_scale: float,
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
        pv = probe_vertex[0]
        mode = probe_mode[0]
        for i in range(wp.tid(), counts[0], stride):
            v = free_vertex[i]
            x = q_in[v]
            u = qd_in[v]
            f = vertex_force(x, u, q_rest[v], anchor_ke[v], anchor_kd[v], anchor_scale,
                             entry_offsets[v], entry_offsets[v + 1], entry_topology, entry_params, 0, q_in, qd_in, pressure)
            if v == pv and mode != 0:
                probe_reaction[0] = f  # the feedback force: the tissue's internal forces on the probe
            if v == pv and mode == 1:
                xd, ud = drive_vertex(x, probe_target[0], dt)  # displacement control
                q_out[v] = xd
                qd_out[v] = ud
            else:
                if v == pv and mode == 2:
                    f += probe_force[0]
                x1, u1 = advance(x, u, dt * f / particle_mass[v], dt)
                q_out[v] = x1
                qd_out[v] = u1

    return integrate_region_explicit


@wp.kernel
def constrain_sphere_explicit(
    free_vertex: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    particle_mass: wp.array(dtype=wp.float32),
    probe: ProbeArrays,
    sphere: ProbeSphereArrays,
    dt: float,
    q_in: wp.array(dtype=wp.vec3),
    qd_in: wp.array(dtype=wp.vec3),
    q_out: wp.array(dtype=wp.vec3),
    qd_out: wp.array(dtype=wp.vec3),
):
    # one thread: the sphere (centre probe_target) after the step; the feedback force is the sum of
    # the contact reactions, in local order
    if probe.probe_mode[0] != 3:
        return
    centre = probe.probe_target[0]
    radius = sphere.probe_radius[0]
    total = wp.vec3(0.0)
    for i in range(counts[0]):
        v = free_vertex[i]
        contact = wp.vec3(0.0)
        if sphere.probe_surface[v] != 0:
            x1, u1, c, touched = sphere_contact_step(q_in[v], qd_in[v], q_out[v], qd_out[v], particle_mass[v], centre, radius, dt)
            if touched:
                q_out[v] = x1
                qd_out[v] = u1
                contact = c
                total += contact
        sphere.probe_contact[v] = contact
    probe.probe_reaction[0] = total


def integrate_explicit(model, free_vertex, counts, threads, anchor_scale, state_in, state_out, control, dt, tets=None):
    """Advance the free vertices (the first counts[0] of `free_vertex`; counts: a device int32 array,
    read when the launch runs, counts[1] the region's vertices, free and fixed ring) by one
    semi-implicit Euler step of `dt` [s], on `threads` threads (1 on the CPU; on CUDA at least the
    free count: both launches stride over their vertices); a volumetric law's nodal pressures first
    (`tets`, the region's RegionTets built for this free set: each tet's volume and forces once,
    kernels/region/volumes.py; None: update_pressure, each vertex's tets), a Control with a sphere adds the sphere's contact (a
    one-thread launch after)."""
    if tets is not None:
        tets.pressures(free_vertex, counts, threads, state_in.particle_q, forces=True)
        topology, params = tets.arrays.entry_corner, tets.arrays.force
    else:
        update_pressure(model, free_vertex, counts, threads, state_in.particle_q)
        topology, params = model.entry_topology, model.entry_params
    wp.launch(
        region_kernel(model.law, tets is not None),
        dim=threads,
        inputs=[
            free_vertex, counts, threads, model.entry_offsets, topology, params, model.nodal_pressure,
            model.particle_q_rest,
            model.particle_mass, model.anchor_ke, model.anchor_kd, anchor_scale,
            control.probe_vertex, control.probe_mode, control.probe_target, control.probe_force, dt,
            state_in.particle_q, state_in.particle_qd,
        ],
        outputs=[state_out.particle_q, state_out.particle_qd, control.probe_reaction],
        device=model.device,
    )
    if control.sphere:
        wp.launch(
            constrain_sphere_explicit,
            dim=1,
            inputs=[
                free_vertex, counts, model.particle_mass, control.arrays, control.sphere_arrays, dt,
                state_in.particle_q, state_in.particle_qd,
            ],
            outputs=[state_out.particle_q, state_out.particle_qd],
            device=model.device,
        )
